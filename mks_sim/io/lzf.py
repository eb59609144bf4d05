"""LZF (liblzf) decompression and a simple compressor, pure Python.

PCL writes ``DATA binary_compressed`` point clouds with LZF. The format is a stream of
control bytes: ``c < 32`` starts a literal run of ``c + 1`` bytes; otherwise ``c >> 5`` is a
back-reference length (7 means "add the next byte"), and the offset is
``((c & 0x1f) << 8) + next byte + 1`` bytes back; ``length + 2`` bytes are copied.
"""

from __future__ import annotations

__all__ = ["lzf_compress", "lzf_decompress"]


class LZFError(ValueError):
    """A malformed LZF stream (the caller turns it into a DataError naming the file)."""


def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """Decompress an LZF stream.

    Args:
        data: The compressed bytes.
        expected_size: The decompressed size the container announced.

    Raises:
        LZFError: when the stream is malformed or does not decompress to ``expected_size``.
    """
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            run = ctrl + 1
            if i + run > n:
                raise LZFError(f"literal run of {run} bytes at offset {i - 1} passes the end")
            out += data[i : i + run]
            i += run
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise LZFError("stream ends inside a back-reference")
            length += data[i]
            i += 1
        if i >= n:
            raise LZFError("stream ends inside a back-reference")
        ref = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
        i += 1
        length += 2
        if ref < 0:
            raise LZFError(f"back-reference before the start of the output at offset {i - 2}")
        if ref + length <= len(out):
            out += out[ref : ref + length]
        else:  # overlapping copy: repeat the pattern
            period = len(out) - ref
            chunk = bytes(out[ref:])
            reps = -(-length // period)
            out += (chunk * reps)[:length]
        if len(out) > expected_size:
            break
    if len(out) != expected_size:
        raise LZFError(f"decompressed to {len(out)} bytes, the header says {expected_size}")
    return bytes(out)


def lzf_compress(data: bytes) -> bytes:
    """Compress with LZF (greedy, 3-byte hash; slow pure Python: for tests and small clouds)."""
    out = bytearray()
    lit = bytearray()
    table: dict[bytes, int] = {}
    i, n = 0, len(data)

    def flush() -> None:
        for k in range(0, len(lit), 32):
            part = lit[k : k + 32]
            out.append(len(part) - 1)
            out.extend(part)
        lit.clear()

    while i < n:
        if i + 2 < n:
            key = data[i : i + 3]
            ref = table.get(key)
            table[key] = i
            if ref is not None and 0 < i - ref <= 8192:
                length = 3
                max_len = min(264, n - i)
                while length < max_len and data[ref + length] == data[i + length]:
                    length += 1
                flush()
                off = i - ref - 1
                ln = length - 2
                if ln < 7:
                    out.append((ln << 5) | (off >> 8))
                else:
                    out.append((7 << 5) | (off >> 8))
                    out.append(ln - 7)
                out.append(off & 0xFF)
                i += length
                continue
        lit.append(data[i])
        i += 1
    flush()
    return bytes(out)
