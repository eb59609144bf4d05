"""Characteristic output vectors: don't care, validation policies, coercion, merging."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mks_sim.errors import DataError, NotFound, SpecError
from mks_sim.fields import (
    DONT_CARE,
    DontCare,
    Field,
    OutputVector,
    Stream,
    coarser,
    coerce,
    coerce_stream,
    merge_streams,
    parse_reference,
    parse_reference_vector,
    reference_vector,
)

# The paper's camera (section 1.1) and a half-resolution one.
CAM_X_1024 = Field("x", 0, 1023, "px")
CAM_X_512 = Field("x", 0, 511, "px")


def camera_vector(x: Field, y_high: int) -> OutputVector:
    return OutputVector.of(x, Field("y", 0, y_high, "px"), Field("intensity", 0, 255))


# --------------------------------------------------------------------------- don't care


def test_dont_care_is_a_singleton_written_star() -> None:
    assert DontCare() is DONT_CARE
    assert repr(DONT_CARE) == "'*'" and str(DONT_CARE) == "*"
    assert pickle.loads(pickle.dumps(DONT_CARE)) is DONT_CARE
    assert copy.deepcopy(DONT_CARE) is DONT_CARE


def test_parse_reference_values() -> None:
    assert parse_reference("*") is DONT_CARE
    assert parse_reference(DONT_CARE) is DONT_CARE
    assert parse_reference(2) == 2.0 and isinstance(parse_reference(2), float)
    assert parse_reference(2.5) == 2.5
    with pytest.raises(SpecError, match=r"model C2: radius: expected a number or '\*'.*'abc'"):
        parse_reference("abc", where="model C2: radius")
    with pytest.raises(SpecError, match="finite"):
        parse_reference(float("nan"))
    with pytest.raises(SpecError, match="got True"):
        parse_reference(True)


def test_parse_reference_vector_for_circle_model_c2() -> None:
    # Paper section 2.1: model C2 = circles of radius 2, x and y don't care.
    circle = OutputVector.of(Field("x", 0, 1024), Field("y", 0, 1024), Field("radius", 0, 512))
    refs = parse_reference_vector(["*", "*", 2], circle, where="C2")
    assert refs == (DONT_CARE, DONT_CARE, 2.0)
    idx, values = reference_vector(refs)  # the k-vector of C2 is (radius,)
    np.testing.assert_array_equal(idx, [2])
    np.testing.assert_array_equal(values, [2.0])
    with pytest.raises(SpecError, match=r"C2: expected 3 values.*got 2"):
        parse_reference_vector(["*", 2], circle, where="C2")
    with pytest.raises(SpecError, match=r"\[2\] \(radius\): expected a value in 0:512"):
        parse_reference_vector(["*", "*", 600], circle, where="C2")
    with pytest.raises(SpecError, match="expected a list"):
        parse_reference_vector("**2", circle)


# --------------------------------------------------------------------------- fields


def test_field_precision_from_integer_range_or_resolution() -> None:
    assert CAM_X_1024.resolution == 1.0 and CAM_X_1024.levels == 1024
    assert Field("z", 0.0, 1.0).resolution is None
    assert Field("z", 0.0, 1.0).levels == float("inf")
    assert Field("z", 0.0, 1.0, resolution=0.25).levels == 5


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"low": 1, "high": 1}, "expected low < high"),
        ({"low": "a", "high": 1}, "low: expected a finite number, got 'a'"),
        ({"low": 0, "high": float("inf")}, "high: expected a finite number"),
        ({"low": 0, "high": 1, "policy": "drop"}, "policy: expected one of"),
        ({"low": 0, "high": 1, "resolution": 0}, "resolution: expected a positive number"),
        ({"low": 0, "high": 1, "coercion": "x"}, "coercion: expected one of"),
    ],
)
def test_field_rejects_bad_values(kwargs: dict, match: str) -> None:
    with pytest.raises(SpecError, match=match):
        Field("f", **kwargs)


def test_output_vector_names_and_index() -> None:
    vec = camera_vector(CAM_X_1024, 1023)
    assert vec.names == ("x", "y", "intensity")
    assert len(vec) == 3 and vec.index("intensity") == 2
    np.testing.assert_array_equal(vec.highs, [1023, 1023, 255])
    with pytest.raises(NotFound, match=r"no field 'z'.*\['x', 'y', 'intensity'\]"):
        vec.index("z")
    with pytest.raises(SpecError, match="duplicate field name"):
        OutputVector.of(CAM_X_1024, CAM_X_512)
    with pytest.raises(SpecError, match="at least one field"):
        OutputVector(())


# --------------------------------------------------------------------------- validation

VEC = OutputVector.of(
    Field("a", 0.0, 10.0, policy="reject"),
    Field("b", 0.0, 1.0, policy="clip"),
    Field("c", 0.0, 1.0, policy="flag"),
)


def test_reject_policy_drops_and_counts() -> None:
    data = [[1, 0.5, 0.5], [11, 0.5, 0.5], [-1, 0.5, 0.5], [np.nan, 0.5, 0.5], [2, 0.5, 0.5]]
    out = VEC.validate(data)
    np.testing.assert_array_equal(out.data[:, 0], [1, 2])
    np.testing.assert_array_equal(out.kept, [True, False, False, False, True])
    rep = out.report
    assert (rep.rows_in, rep.rows_out, rep.dropped) == (5, 2, 3)
    a = rep.field("a")
    assert (a.out_of_range, a.nan, a.rejected) == (2, 1, 3)
    assert "3 dropped" in rep.summary() and "a: 2 out of range, 1 NaN (rejected 3)" in str(rep)
    assert not rep.clean


def test_reject_policy_strict_raises() -> None:
    with pytest.raises(DataError, match=r"sensors/x.toml: strict validation failed: 2 rows in"):
        VEC.validate([[1, 0.5, 0.5], [11, 0.5, 0.5]], strict=True, where="sensors/x.toml")
    # Clipping and flagging are not data loss: strict accepts them.
    out = VEC.validate([[1, 2.0, 2.0]], strict=True)
    assert out.report.rows_out == 1


def test_clip_policy_clips_and_counts_nan_rows_dropped() -> None:
    out = VEC.validate([[1, 1.5, 0.5], [1, -0.25, 0.5], [1, 0.25, 0.5], [1, np.nan, 0.5]])
    np.testing.assert_array_equal(out.data[:, 1], [1.0, 0.0, 0.25])
    b = out.report.field("b")
    assert (b.clipped, b.out_of_range, b.nan, b.rejected) == (2, 2, 1, 1)
    assert out.report.dropped == 1
    assert not out.flags.any()


def test_flag_policy_keeps_and_flags() -> None:
    out = VEC.validate([[1, 0.5, 1.5], [1, 0.5, np.nan], [1, 0.5, 0.5], [1, 0.5, -np.inf]])
    assert out.data.shape == (4, 3)
    np.testing.assert_array_equal(out.flags[:, 2], [True, True, False, True])
    assert not out.flags[:, :2].any()
    assert np.isnan(out.data[1, 2]) and out.data[0, 2] == 1.5  # kept as is
    c = out.report.field("c")
    assert (c.flagged, c.nan, c.out_of_range, c.rejected) == (3, 1, 2, 0)
    assert out.report.dropped == 0


def test_validate_bad_shapes() -> None:
    with pytest.raises(DataError, match=r"S: expected an \(N, 3\) array, got shape \(2, 2\)"):
        VEC.validate([[1, 2], [3, 4]], where="S")
    with pytest.raises(DataError, match="numeric"):
        VEC.validate([["a", "b", "c"]])
    empty = VEC.validate([])
    assert empty.data.shape == (0, 3) and empty.report.clean


# --------------------------------------------------------------------------- coercion


def test_coerce_paper_camera_1023_to_511_hand_computed() -> None:
    # v' = v * 511 / 1023, rounded half up: 2 -> 0.999 -> 1; 3 -> 1.4985 -> 1;
    # 512 -> 255.75 -> 256; 1021 -> 510.001 -> 510; 1022 -> 510.5005 -> 511; 1023 -> 511.
    assert coarser(CAM_X_1024, CAM_X_512) is CAM_X_512
    assert coarser(CAM_X_512, CAM_X_1024) is CAM_X_512
    got = coerce([0, 1, 2, 3, 512, 1021, 1022, 1023], CAM_X_1024, CAM_X_512)
    np.testing.assert_array_equal(got, [0, 0, 1, 1, 256, 510, 511, 511])


def test_coerce_continuous_and_requantize() -> None:
    fine = Field("z", 0.0, 2.0, "m")
    coarse = Field("z", 0.0, 1.0, "m", resolution=0.25)
    np.testing.assert_allclose(coerce([0.0, 0.3, 1.0, 2.0], fine, coarse), [0, 0.25, 0.5, 1.0])
    # Absolute quantities (metres): the value is kept, only its precision is reduced.
    mm = Field("z", -1.0, 1.0, "m", resolution=0.001, coercion="requantize")
    cm = Field("z", -1.0, 1.0, "m", resolution=0.01, coercion="requantize")
    assert coarser(mm, cm) is cm
    np.testing.assert_allclose(coerce([0.123, -0.457, 0.0], mm, cm), [0.12, -0.46, 0.0])
    assert np.isnan(coerce([np.nan], CAM_X_1024, CAM_X_512)[0])


def test_coerce_incompatible_fields() -> None:
    with pytest.raises(DataError, match="incompatible units 'px' and 'm'"):
        coarser(CAM_X_1024, Field("x", 0.0, 1.0, "m"))
    with pytest.raises(DataError, match="cannot coerce field 'x' into field 'y'"):
        coerce([1], CAM_X_1024, Field("y", 0, 511, "px"))
    with pytest.raises(DataError, match="incompatible coercion modes"):
        coarser(CAM_X_1024, Field("x", 0, 511, "px", coercion="requantize"))


@given(
    hi_fine=st.integers(2, 5000),
    hi_coarse=st.integers(1, 5000),
    values=st.lists(st.floats(-100, 6000, allow_nan=False), min_size=2, max_size=30),
)
def test_coerce_is_monotone_and_in_range(hi_fine: int, hi_coarse: int, values: list) -> None:
    src, dst = Field("x", 0, hi_fine), Field("x", 0, hi_coarse)
    v = np.sort(np.asarray(values))
    out = coerce(v, src, dst)
    assert np.all(np.diff(out) >= 0)
    assert out.min() >= 0 and out.max() <= hi_coarse
    np.testing.assert_array_equal(out, np.round(out))  # quantised to integers
    # The ends of the range map onto the ends of the range.
    np.testing.assert_array_equal(coerce([0, hi_fine], src, dst), [0, hi_coarse])


@given(st.lists(st.integers(0, 511), min_size=1, max_size=20))
def test_coerce_onto_itself_is_identity(values: list) -> None:
    np.testing.assert_array_equal(coerce(values, CAM_X_512, CAM_X_512), values)


# --------------------------------------------------------------------------- streams


def test_stream_checks_shapes_and_is_read_only() -> None:
    vec = camera_vector(CAM_X_512, 511)
    s = Stream([[1, 2, 3], [4, 5, 6]], vec, "cam")
    assert len(s) == 2 and s.served_by == "primary"
    np.testing.assert_array_equal(s.column("y"), [2, 5])
    with pytest.raises(ValueError, match="read-only"):
        s.data[0, 0] = 9
    sub = s.select(["intensity", "x"])
    assert sub.names == ("intensity", "x")
    np.testing.assert_array_equal(sub.data, [[3, 1], [6, 4]])
    with pytest.raises(DataError, match=r"stream of 'cam': expected an \(N, 3\) array"):
        Stream([[1, 2]], vec, "cam")
    with pytest.raises(DataError, match=r"source: expected shape \(2,\)"):
        Stream([[1, 2, 3], [4, 5, 6]], vec, "cam", source=np.array(["a"]))
    with pytest.raises(DataError, match="flags: expected shape"):
        Stream([[1, 2, 3]], vec, "cam", flags=np.zeros((2, 3), bool))


def test_merge_streams_coerces_to_coarser_and_keeps_provenance() -> None:
    big = Stream([[1023, 1023, 200], [512, 0, 10]], camera_vector(CAM_X_1024, 1023), "cam_hi")
    small = Stream([[5, 6, 7]], camera_vector(CAM_X_512, 511), "cam_lo")
    merged = merge_streams([big, small], sensor="Cameras")
    assert merged.vector.field("x") == CAM_X_512 and merged.vector.field("y").high == 511
    assert merged.vector.field("intensity").high == 255
    np.testing.assert_array_equal(merged.data, [[511, 511, 200], [256, 0, 10], [5, 6, 7]])
    assert list(merged.source) == ["cam_hi", "cam_hi", "cam_lo"]
    assert merged.sensor == "Cameras" and merged.report is not None
    assert merged.report.clean
    # A merged stream merges again, its per-row source preserved.
    again = merge_streams([merged, small])
    assert list(again.source) == ["cam_hi", "cam_hi", "cam_lo", "cam_lo"]


def test_merge_streams_carries_flags_and_validates() -> None:
    vec = OutputVector.of(Field("d", 0.0, 1.0, "m", policy="flag"))
    a = Stream([[0.5], [2.0]], vec, "a", flags=np.array([[False], [True]]))
    b = Stream([[0.1]], vec, "b")
    merged = merge_streams([a, b])
    np.testing.assert_array_equal(merged.flags, [[False], [True], [False]])


def test_merge_streams_errors() -> None:
    cam = Stream([[1, 2, 3]], camera_vector(CAM_X_512, 511), "cam")
    other = Stream([[1, 2]], OutputVector.of(Field("x", 0, 511, "px"), Field("z", 0, 1)), "o")
    with pytest.raises(DataError, match=r"stream of 'o' has fields \['x', 'z'\]"):
        merge_streams([cam, other])
    metres = Stream([[1, 2, 3]], camera_vector(Field("x", 0, 511, "m"), 511), "m")
    with pytest.raises(DataError, match=r"incompatible units 'px' and 'm'.*'cam' and 'm'"):
        merge_streams([cam, metres])
    with pytest.raises(DataError, match="at least one stream"):
        merge_streams([])


def test_coerce_stream_names_must_match() -> None:
    cam = Stream([[1, 2, 3]], camera_vector(CAM_X_512, 511), "cam")
    with pytest.raises(DataError, match="do not match"):
        coerce_stream(cam, OutputVector.of(CAM_X_512))


def test_coerce_quantises_onto_the_target_grid_even_for_the_same_field() -> None:
    # Sub-pixel circle centres of the coarse camera itself are put on its 1-pixel grid too,
    # so a merged stream has one precision.
    np.testing.assert_array_equal(coerce([10.4, 10.6, 510.9], CAM_X_512, CAM_X_512), [10, 11, 511])


def test_output_vector_coerce_column_by_column() -> None:
    hi, lo = camera_vector(CAM_X_1024, 1023), camera_vector(CAM_X_512, 511)
    got = hi.coerce([[1023, 512, 128], [2, 3, 255]], lo)
    np.testing.assert_array_equal(got, [[511, 256, 128], [1, 1, 255]])
    with pytest.raises(DataError, match="same names in the same order"):
        hi.coerce([[1, 2, 3]], OutputVector.of(CAM_X_512))


_values = st.one_of(
    st.floats(-20, 20, allow_nan=False),
    st.just(float("nan")),
    st.just(float("inf")),
    st.just(float("-inf")),
)


@given(st.lists(st.tuples(_values, _values, _values), max_size=25))
def test_validate_matches_a_row_by_row_reference(rows: list) -> None:
    data = np.array(rows, dtype=float).reshape(-1, 3)
    out = VEC.validate(data)
    lows, highs = VEC.lows, VEC.highs
    kept_rows, kept_flags = [], []
    for row in data:
        a, b, c = row
        if not (lows[0] <= a <= highs[0]) or np.isnan(b):  # NaN compares False: rejected
            continue
        kept_rows.append([a, min(max(b, lows[1]), highs[1]), c])
        kept_flags.append(not (lows[2] <= c <= highs[2]))
    expected = np.array(kept_rows, dtype=float).reshape(-1, 3)
    np.testing.assert_array_equal(out.data, expected)
    np.testing.assert_array_equal(out.flags[:, 2], kept_flags)
    assert out.report.rows_in == len(data) and out.report.rows_out == len(expected)
    assert out.report.field("b").clipped == int(
        np.sum(~np.isnan(data[:, 1]) & ((data[:, 1] < 0) | (data[:, 1] > 1)))
    )


@given(
    highs=st.lists(st.integers(1, 2000), min_size=1, max_size=4),
    sizes=st.lists(st.integers(0, 6), min_size=4, max_size=4),
)
def test_merge_streams_rows_in_coarsest_range_with_provenance(highs: list, sizes: list) -> None:
    rng = np.random.default_rng(len(highs))
    streams = []
    for k, high in enumerate(highs):
        vec = OutputVector.of(Field("u", 0, high, "px"), Field("w", 0.0, 1.0))
        n = sizes[k]
        data = np.column_stack([rng.integers(0, high + 1, n), rng.random(n)])
        streams.append(Stream(data, vec, f"s{k}"))
    merged = merge_streams(streams)
    coarsest = min(highs)
    assert merged.vector.field("u").high == coarsest
    assert len(merged) == sum(sizes[: len(highs)])
    assert merged.source is not None
    for k in range(len(highs)):
        assert int(np.sum(merged.source == f"s{k}")) == sizes[k]
    u = merged.column("u")
    assert np.all((u >= 0) & (u <= coarsest)) and np.all(u == np.round(u))
    # Rows of the coarsest stream itself are unchanged.
    k_min = highs.index(coarsest)
    np.testing.assert_array_equal(merged.data[merged.source == f"s{k_min}"], streams[k_min].data)
