"""The trace reader's compiled loops against plain references: line ends, the numeric fast
path (exactly the float64 a correct parser gives), MAC canonicalisation, duplicate picking, and
the packed-key sort."""

from __future__ import annotations

import re

import numpy as np
import pyarrow as pa
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.line_scan import _newline_ends, best_of_runs, canonical_macs, scan_lines
from survey.trace_reader import _GROUP_OF_INDEX, _GROUP_SPECS, _TYPE_LIST, _lex_order, \
    _read_block, parse_trace_bytes

LAYOUTS = ["fffi", "ffffffi", None, None, "ff"]


def _scan(text: bytes):
    buf = np.frombuffer(text + bytes(64), dtype=np.uint8)
    return scan_lines(buf, len(text), _TYPE_LIST, _GROUP_OF_INDEX, LAYOUTS)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 7))
def test_newline_ends_match_numpy(data, shift):
    # Any offset of the text within its buffer (the word view is then unaligned).
    raw = np.frombuffer(bytes(shift) + data + bytes(8), dtype=np.uint8)[shift:shift + len(data)]
    n = len(data)
    words = raw[:n - n % 8].view(np.uint64)
    expected = np.flatnonzero(raw == 10) + 1
    if n and data[-1:] != b"\n":
        expected = np.append(expected, n + 1)
    assert np.array_equal(_newline_ends(raw, words, n), expected)


decimal = st.builds(
    lambda neg, whole, frac: ("-" if neg else "") + whole + ("." + frac if frac else ""),
    st.booleans(), st.text("0123456789", min_size=1, max_size=12),
    st.text("0123456789", max_size=12))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(decimal, decimal, decimal, st.integers(-99, 99)), min_size=1,
                max_size=20))
def test_scan_parses_plain_decimals_exactly(rows):
    text = "".join(f"{1000 + i}\tTYPE_ACCELEROMETER\t{x}\t{y}\t{z}\t{a}\n"
                   for i, (x, y, z, a) in enumerate(rows)).encode()
    sc = _scan(text)
    parsed, values = sc.group_parsed[0], sc.group_values[0]
    for i, (x, y, z, a) in enumerate(rows):
        digits = max(len(re.sub(r"\D", "", v)) for v in (x, y, z))
        assert parsed[i] == (digits <= 15)  # longer mantissas go to the general parser
        if parsed[i]:
            assert sc.group_t_ms[0][i] == 1000 + i
            got = values[:, i]
            assert [got[0], got[1], got[2], got[3]] == [float(x), float(y), float(z), a]
            assert all(np.signbit(g) == np.signbit(float(v)) for g, v in zip(got, (x, y, z)))
    # Where the scan took a line, pyarrow's parser reads the same values bit for bit.
    block = "".join(f"{1000 + i}\t{x}\t{y}\t{z}\t{a}\n" for i, (x, y, z, a) in enumerate(rows))
    arrow = _read_block(np.frombuffer(block.encode(), np.uint8), _GROUP_SPECS[0], len(rows))
    for j, c in enumerate(("x", "y", "z")):
        assert np.array_equal(values[j][parsed].view(np.int64),
                              arrow[c][parsed].view(np.int64))


def test_other_spellings_go_to_the_general_parser_and_read_the_same():
    spellings = ["1e3", "+1.5", ".5", "2.", "1E-2", " 3", "0x10", "nan", "-inf",
                 "123456.7890123456", "0.000000000000000000001", "-0"]  # 16 digits, < 1e6 m
    lines = [f"{10 + i}\tTYPE_WAYPOINT\t{s}\t1.25\n" for i, s in enumerate(spellings)]
    sc = _scan("".join(lines).encode())
    assert sc.group_parsed[4].tolist() == [False] * 11 + [True]
    trace = parse_trace_bytes("".join(lines).encode())
    # NaN/inf are refused as non-finite; "0x10" is not a float; the rest read as Python does.
    expected = {s: float(s) for s in spellings if s not in ("nan", "-inf", "0x10")}
    got = dict(zip(trace.waypoints["t_ms"] - 10, trace.waypoints["x_m"]))
    assert {spellings[t]: v for t, v in got.items()} == expected
    assert trace.report.bad == {"non_finite": 2, "non_numeric": 1}


def test_scan_keeps_crlf_and_unterminated_lines():
    text = b"5\tTYPE_WAYPOINT\t1.5\t2\r\n6\tTYPE_WAYPOINT\t3\t4"
    sc = _scan(text)
    assert sc.group_parsed[4].tolist() == [True, True]
    assert sc.group_values[4][:2].tolist() == [[1.5, 3.0], [2.0, 4.0]]
    wifi = b"7\tTYPE_WIFI\tap\tAA:BB:CC:DD:EE:FF\t-50\t2412\t6"
    assert bytes(_scan(wifi).group_bytes[2]) == b"7\tap\tAA:BB:CC:DD:EE:FF\t-50\t2412\t6\n"


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(
    st.binary(min_size=6, max_size=6).map(lambda b: ":".join(f"{x:02X}" for x in b)),
    st.text("0123456789abcdefABCDEFG:-", min_size=15, max_size=19)), max_size=30))
def test_canonical_macs_match_a_regex(values):
    arr = pa.array(values, type=pa.string())
    offsets = np.frombuffer(arr.buffers()[1], dtype=np.int32, count=len(arr) + 1)
    data = np.frombuffer(arr.buffers()[2], dtype=np.uint8) if arr.buffers()[2] \
        else np.zeros(0, np.uint8)
    rows, ok = canonical_macs(offsets, data)
    for i, v in enumerate(values):
        assert ok[i] == bool(re.fullmatch(r"[0-9a-fA-F]{2}(:[0-9a-fA-F]{2}){5}", v))
        if ok[i]:
            assert bytes(rows[17 * i:17 * i + 17]).decode() == v.lower()


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2), st.integers(0, 3), st.integers(0, 3),
                          st.integers(-5, 5), st.integers(-5, 5)), max_size=40))
def test_best_of_runs_keeps_the_first_best_row_per_run(rows):
    rows = sorted(rows, key=lambda r: r[:3])  # stable: equal keys stay in input order
    a, b, c, s1, s2 = (np.array([r[k] for r in rows], dtype=np.int64) for k in range(5))
    drop = best_of_runs(a, b, c, s1, s2)
    kept = {}
    for i, r in enumerate(rows):
        best = kept.get(r[:3])
        if best is None or (r[3], r[4]) > (rows[best][3], rows[best][4]):
            kept[r[:3]] = i
    assert sorted(np.flatnonzero(~drop).tolist()) == sorted(kept.values())


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(-2**62, 2**62), st.integers(0, 9)),
                max_size=40), st.booleans())
def test_lex_order_equals_lexsort(rows, small):
    keys = [np.array([r[k] for r in rows], dtype=np.int64) for k in range(3)]
    if small:  # ranges that pack into one int64
        keys[1] = keys[1] % 1000
    assert np.array_equal(_lex_order(*keys), np.lexsort(keys[::-1]))
