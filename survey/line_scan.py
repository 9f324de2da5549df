"""One compiled pass over trace text: lines, their kind and record type, and per-layout blocks.

This is the hot loop of the trace reader, compiled with numba (``cache=True``: compiled once per
installation). In one pass over the bytes it finds every line, checks the timestamp field,
matches the record-type token against the documented names, and copies the lines of each value
layout ("group") into that group's own buffer, ready for pyarrow's CSV parser.
"""

from __future__ import annotations

import numba
import numpy as np

#: Line kinds returned by :func:`scan_lines`.
BLANK, HEADER, RECORD, NO_TAB, BAD_TIMESTAMP, BAD_TOKEN, OTHER_TOKEN = range(7)
TS_WIDTH = 16
TOKEN_WIDTH = 48


@numba.njit(cache=True, nogil=True)
def _scan(buf, n, names, name_lens, group_of_name, n_groups):  # pragma: no cover - compiled
    n_lines = 0
    for i in range(n):
        if buf[i] == 10:
            n_lines += 1
    if n > 0 and buf[n - 1] != 10:
        n_lines += 1
    starts = np.empty(n_lines, np.int64)
    ends = np.empty(n_lines, np.int64)
    nexts = np.empty(n_lines, np.int64)
    kind = np.empty(n_lines, np.int8)
    type_idx = np.full(n_lines, -1, np.int16)
    tok_start = np.zeros(n_lines, np.int64)
    tok_len = np.zeros(n_lines, np.int32)
    group_bytes = np.zeros(n_groups, np.int64)
    group_lines = np.zeros(n_groups, np.int64)
    n_names = names.shape[0]

    pos = 0
    for li in range(n_lines):
        s = pos
        e = s
        while e < n and buf[e] != 10:
            e += 1
        nxt = e + 1
        starts[li] = s
        nexts[li] = nxt
        if e > s and buf[e - 1] == 13:
            e -= 1
        ends[li] = e
        pos = nxt
        if e == s:
            kind[li] = BLANK
            continue
        if buf[s] == 35:  # '#'
            kind[li] = HEADER
            continue
        t1 = s
        while t1 < e and buf[t1] != 9:
            t1 += 1
        if t1 == e:
            kind[li] = NO_TAB
            continue
        ts_ok = 1 <= t1 - s <= TS_WIDTH
        if ts_ok:
            for j in range(s, t1):
                if buf[j] < 48 or buf[j] > 57:
                    ts_ok = False
                    break
        if not ts_ok:
            kind[li] = BAD_TIMESTAMP
            continue
        t2 = t1 + 1
        while t2 < e and buf[t2] != 9:
            t2 += 1
        length = t2 - t1 - 1
        if length < 1 or length > TOKEN_WIDTH:
            kind[li] = BAD_TOKEN
            continue
        tok_start[li] = t1 + 1
        tok_len[li] = length
        found = -1
        for k in range(n_names):
            if name_lens[k] != length:
                continue
            same = True
            for j in range(length):
                if buf[t1 + 1 + j] != names[k, j]:
                    same = False
                    break
            if same:
                found = k
                break
        if found < 0:
            kind[li] = OTHER_TOKEN
            continue
        kind[li] = RECORD
        type_idx[li] = found
        g = group_of_name[found]
        group_bytes[g] += nxt - s
        group_lines[g] += 1

    # Copy each group's lines (with their newline) into one buffer per group.
    total = 0
    for g in range(n_groups):
        total += group_bytes[g]
    out = np.empty(total, np.uint8)
    out_off = np.zeros(n_groups + 1, np.int64)
    for g in range(n_groups):
        out_off[g + 1] = out_off[g] + group_bytes[g]
    line_off = np.zeros(n_groups + 1, np.int64)
    for g in range(n_groups):
        line_off[g + 1] = line_off[g] + group_lines[g]
    lines_of_group = np.empty(line_off[n_groups], np.int64)
    wpos = out_off[:n_groups].copy()
    lpos = line_off[:n_groups].copy()
    for li in range(n_lines):
        if kind[li] != RECORD:
            continue
        g = group_of_name[type_idx[li]]
        s = starts[li]
        m = nexts[li] - s
        if s + m > n:  # the final line had no newline: supply one
            m = n - s
            out[wpos[g]:wpos[g] + m] = buf[s:s + m]
            out[wpos[g] + m] = 10
            m += 1
        else:
            out[wpos[g]:wpos[g] + m] = buf[s:s + m]
        wpos[g] += m
        lines_of_group[lpos[g]] = li
        lpos[g] += 1
    return (starts, ends, nexts, kind, type_idx, tok_start, tok_len, out, out_off,
            lines_of_group, line_off)


class ScanResult:
    """Per-line arrays (``starts``, ``ends`` without newline/CR, ``kind``, ``type_idx``,
    ``tok_start``, ``tok_len``) and per group the joined bytes and global line indices."""

    def __init__(self, raw, n_groups: int) -> None:
        (self.starts, self.ends, self.nexts, self.kind, self.type_idx, self.tok_start,
         self.tok_len, out, out_off, lines_of_group, line_off) = raw
        self.group_bytes = [out[out_off[g]:out_off[g + 1]] for g in range(n_groups)]
        self.group_lines = [lines_of_group[line_off[g]:line_off[g + 1]] for g in range(n_groups)]


def scan_lines(buf: np.ndarray, n: int, type_names: list[str],
               group_of_type: np.ndarray) -> ScanResult:
    """Scan ``buf[:n]`` (uint8) for lines and documented record types.

    Parameters
    ----------
    buf : ndarray of uint8
        The text.
    n : int
        Bytes of text in ``buf``.
    type_names : list of str
        Documented record types; ``type_idx`` indexes this list.
    group_of_type : ndarray of int
        Value-layout group of each documented type.
    """
    n_groups = int(group_of_type.max()) + 1
    names = np.zeros((len(type_names), TOKEN_WIDTH), dtype=np.uint8)
    lens = np.zeros(len(type_names), dtype=np.int64)
    for k, name in enumerate(type_names):
        raw = name.encode("ascii")
        names[k, :len(raw)] = np.frombuffer(raw, dtype=np.uint8)
        lens[k] = len(raw)
    raw = _scan(buf, n, names, lens, group_of_type.astype(np.int64), n_groups)
    return ScanResult(raw, n_groups)
