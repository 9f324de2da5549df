"""Compiled loops of the trace reader: lines, their kind and record type, and per-layout blocks;
MAC canonicalisation; duplicate picking.

The line scan is the hot loop of the trace reader, compiled with numba (cached on disk: compiled
once per installation, or per process where no cache folder can be written:
:mod:`survey.compiled`). A first pass finds the line ends (eight bytes per test); a second checks
each line's timestamp field, matches its record-type token against the documented names, parses
the all-numeric layouts (plain decimal spellings) in place, and copies every other line into its
value layout's ("group's") own buffer without the type field, ready for pyarrow's CSV parser.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .compiled import njit_cached

#: Line kinds returned by :func:`scan_lines`.
BLANK, HEADER, RECORD, NO_TAB, BAD_TIMESTAMP, BAD_TOKEN, OTHER_TOKEN = range(7)
TS_WIDTH = 16
TOKEN_WIDTH = 48


_NL_BYTES = np.uint64(0x0A0A0A0A0A0A0A0A)
_LOW7 = np.uint64(0x7F7F7F7F7F7F7F7F)
_HIGH = np.uint64(0x8080808080808080)


@njit_cached(nogil=True)
def _newline_ends(buf, words, n):  # pragma: no cover - compiled
    """Index after each line's last byte (its newline; ``n + 1`` for an unterminated last line).

    ``words`` views the first ``8 * len(words)`` bytes of ``buf`` as uint64: eight bytes are
    tested for a newline at once (a word with none, most of them, costs one test)."""
    n_lines = 0
    for i in range(n):
        if buf[i] == 10:
            n_lines += 1
    if n > 0 and buf[n - 1] != 10:
        n_lines += 1
    nexts = np.empty(n_lines, np.int64)
    li = 0
    n_words = min(len(words), n // 8)
    for w in range(n_words):
        v = words[w] ^ _NL_BYTES
        # high bit of a byte of ``t`` clear <=> that byte of v is zero (no carries across bytes)
        t = ((v & _LOW7) + _LOW7) | v
        if (~t & _HIGH) != 0:
            base = 8 * w
            for j in range(8):
                if buf[base + j] == 10:
                    nexts[li] = base + j + 1
                    li += 1
    for i in range(8 * n_words, n):
        if buf[i] == 10:
            nexts[li] = i + 1
            li += 1
    if li < n_lines:
        nexts[li] = n + 1
    return nexts


# Powers of ten exactly representable as float64 (10**22 is the largest).
_POW10 = np.array([10.0 ** k for k in range(23)])
FLOAT, INT = 0, 1


@njit_cached(nogil=True)
def _digits(buf, p, e, m):  # pragma: no cover - compiled
    """Append the decimal digits from ``buf[p:e]`` to ``m``: (m, digits read, next position)."""
    n = 0
    while p < e and 48 <= buf[p] <= 57:
        m = m * 10 + (buf[p] - 48)
        n += 1
        p += 1
    return m, n, p


@njit_cached(nogil=True)
def _parse_numbers(buf, p, e, kinds, values, r):  # pragma: no cover - compiled
    """Parse ``<TAB>value`` fields from ``buf[p:e]`` into ``values[:, r]`` (float64) by ``kinds``.

    Only the plain spellings are taken: floats ``-?digits(.digits)?`` and integers
    ``-?digits``, at most 15 significant digits in all. Such a decimal is ``m / 10**k`` with
    ``m < 2**53`` and ``k <= 22``, both exact in float64, so one correctly rounded division
    gives exactly the nearest float64, as any correct parser (pyarrow's, Python's) does.
    Returns False for anything else (the caller then hands the line to the general parser)."""
    for c in range(len(kinds)):
        if kinds[c] < 0:
            break
        if p >= e or buf[p] != 9:
            return False
        p += 1
        neg = p < e and buf[p] == 45  # '-'
        if neg:
            p += 1
        m, digits, p = _digits(buf, p, e, 0)
        frac = 0
        if digits == 0:
            return False
        if p < e and buf[p] == 46:  # '.'
            if kinds[c] == INT:
                return False
            m, frac, p = _digits(buf, p + 1, e, m)
            if frac == 0:
                return False
        if p < e and buf[p] != 9 or digits + frac > 15:
            return False
        value = float(m) / _POW10[frac] if frac else float(m)
        values[c, r] = -value if neg else value
    return p == e


@njit_cached(nogil=True)
def _scan(buf, n, nexts, names, name_lens, group_of_name, n_groups,
          group_kinds):  # pragma: no cover - compiled
    n_lines = len(nexts)
    starts = np.empty(n_lines, np.int64)
    ends = np.empty(n_lines, np.int64)
    kind = np.empty(n_lines, np.int8)
    type_idx = np.full(n_lines, -1, np.int16)
    tok_start = np.zeros(n_lines, np.int64)
    tok_len = np.zeros(n_lines, np.int32)
    group_bytes = np.zeros(n_groups, np.int64)
    group_lines = np.zeros(n_groups, np.int64)
    # Documented names have distinct lengths (checked by scan_lines): the length picks the name.
    name_of_len = np.full(TOKEN_WIDTH + 1, -1, np.int64)
    for k in range(names.shape[0]):
        name_of_len[name_lens[k]] = k

    nxt = 0
    for li in range(n_lines):
        s = nxt
        nxt = nexts[li]
        e = min(nxt - 1, n)
        starts[li] = s
        if e > s and buf[e - 1] == 13:
            e -= 1
        ends[li] = e
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
        k = name_of_len[length]
        if k >= 0:
            for j in range(length):
                if buf[t1 + 1 + j] != names[k, j]:
                    k = -1
                    break
        if k < 0:
            kind[li] = OTHER_TOKEN
            continue
        kind[li] = RECORD
        type_idx[li] = k
        g = group_of_name[k]
        group_bytes[g] += nxt - s - length - 1
        group_lines[g] += 1

    # Second pass. Lines of a numeric layout (a row of ``group_kinds`` not starting with -1)
    # are parsed here into ``t_ms``/``values``; the others, and numeric lines in any but the
    # plain spelling, are copied into one buffer per group without the record-type field
    # (known per line), "timestamp<TAB>values...<LF>", for the general parser.
    total = 0
    for g in range(n_groups):
        total += group_bytes[g]
    out = np.empty(total, np.uint8)  # an upper bound: pages never written cost nothing
    out_off = np.zeros(n_groups + 1, np.int64)
    for g in range(n_groups):
        out_off[g + 1] = out_off[g] + group_bytes[g]
    line_off = np.zeros(n_groups + 1, np.int64)
    for g in range(n_groups):
        line_off[g + 1] = line_off[g] + group_lines[g]
    n_rec = line_off[n_groups]
    lines_of_group = np.empty(n_rec, np.int64)
    parsed = np.zeros(n_rec, np.bool_)
    t_ms = np.empty(n_rec, np.int64)
    values = np.empty((group_kinds.shape[1], n_rec), np.float64)  # a column per row
    wpos = out_off[:n_groups].copy()
    lpos = line_off[:n_groups].copy()
    for li in range(n_lines):
        if kind[li] != RECORD:
            continue
        g = group_of_name[type_idx[li]]
        r = lpos[g]
        lines_of_group[r] = li
        lpos[g] += 1
        s = starts[li]
        t1 = tok_start[li] - 1
        t2 = tok_start[li] + tok_len[li]  # the tab (or line end) after the type
        if group_kinds[g, 0] >= 0 and _parse_numbers(buf, t2, ends[li], group_kinds[g],
                                                     values, r):
            t = 0
            for j in range(s, t1):
                t = t * 10 + (buf[j] - 48)
            t_ms[r] = t
            parsed[r] = True
            continue
        w = wpos[g]
        m = t1 - s  # the timestamp
        out[w:w + m] = buf[s:s + m]
        w += m
        m = nexts[li] - t2
        if nexts[li] > n:  # the final line had no newline: supply one
            m -= 1
            out[w:w + m] = buf[t2:t2 + m]
            out[w + m] = 10
            m += 1
        else:
            out[w:w + m] = buf[t2:t2 + m]
        wpos[g] = w + m
    return (starts, ends, kind, type_idx, tok_start, tok_len, out, out_off, wpos,
            lines_of_group, line_off, parsed, t_ms, values)


@njit_cached(nogil=True)
def canonical_macs(offsets: NDArray[np.int32],  # pragma: no cover - compiled
                   data: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """Lower-case 17-byte ``xx:xx:xx:xx:xx:xx`` strings of an Arrow string array.

    ``offsets`` (int32, n + 1) and ``data`` (uint8) are the array's buffers. Returns the
    lower-cased bytes (n * 17, zeros for other lengths) and whether each entry is such a MAC."""
    n = len(offsets) - 1
    out = np.zeros(n * 17, np.uint8)
    ok = np.zeros(n, np.bool_)
    for i in range(n):
        s = offsets[i]
        if offsets[i + 1] - s != 17:
            continue
        good = True
        for j in range(17):
            c = data[s + j]
            if j % 3 == 2:
                good = good and c == 58  # ':'
            else:
                if 65 <= c <= 70:  # A-F
                    c += 32
                good = good and (48 <= c <= 57 or 97 <= c <= 102)
            out[17 * i + j] = c
        ok[i] = good
    return out, ok


@njit_cached(nogil=True)
def best_of_runs(run_key_a: NDArray[np.integer],  # pragma: no cover - compiled
                 run_key_b: NDArray[np.integer], run_key_c: NDArray[np.integer],
                 score_a: NDArray[np.integer], score_b: NDArray[np.integer]
                 ) -> NDArray[np.bool_]:
    """Over rows sorted by the three run keys, mark the first row of each run of equal keys
    with the largest ``(score_a, score_b)`` (earliest row on ties); the rest are duplicates.

    Returns a boolean array: ``True`` for rows to drop."""
    n = len(run_key_a)
    drop = np.ones(n, np.bool_)
    i = 0
    while i < n:
        best = i
        j = i + 1
        while (j < n and run_key_a[j] == run_key_a[i] and run_key_b[j] == run_key_b[i]
               and run_key_c[j] == run_key_c[i]):
            if score_a[j] > score_a[best] or (score_a[j] == score_a[best]
                                              and score_b[j] > score_b[best]):
                best = j
            j += 1
        drop[best] = False
        i = j
    return drop


class ScanResult:
    """Per-line arrays (``starts``, ``ends`` without newline/CR, ``kind``, ``type_idx``,
    ``tok_start``, ``tok_len``) and per value-layout group:

    - ``group_lines``: the global indices of its lines (in file order);
    - ``group_parsed``: which of them were parsed in the scan, with ``group_t_ms`` (int64) and
      ``group_values`` (float64, columns x lines; entries of unparsed lines are undefined);
    - ``group_bytes``: the other lines joined, without their record-type field
      (``timestamp<TAB>values<LF>``), for the general parser.
    """

    def __init__(self, raw, n_groups: int) -> None:
        (self.starts, self.ends, self.kind, self.type_idx, self.tok_start, self.tok_len, out,
         out_off, out_end, lines_of_group, line_off, parsed, t_ms, values) = raw
        self.group_bytes = [out[out_off[g]:out_end[g]] for g in range(n_groups)]
        cut = [slice(line_off[g], line_off[g + 1]) for g in range(n_groups)]
        self.group_lines = [lines_of_group[c] for c in cut]
        self.group_parsed = [parsed[c] for c in cut]
        self.group_t_ms = [t_ms[c] for c in cut]
        self.group_values = [values[:, c] for c in cut]


def scan_lines(buf: np.ndarray, n: int, type_names: list[str], group_of_type: np.ndarray,
               group_layouts: list[str | None]) -> ScanResult:
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
    group_layouts : list of str or None
        Per group, its value columns as a string of ``"f"`` (float) and ``"i"`` (integer) if
        the scan is to parse them, else None.
    """
    n_groups = int(group_of_type.max()) + 1
    names = np.zeros((len(type_names), TOKEN_WIDTH), dtype=np.uint8)
    lens = np.zeros(len(type_names), dtype=np.int64)
    for k, name in enumerate(type_names):
        raw = name.encode("ascii")
        names[k, :len(raw)] = np.frombuffer(raw, dtype=np.uint8)
        lens[k] = len(raw)
    if len(set(lens.tolist())) != len(lens):
        raise ValueError("documented record types must have distinct name lengths")
    width = max([len(x) for x in group_layouts if x] + [1])
    kinds = np.full((n_groups, width), -1, dtype=np.int8)
    for g, layout in enumerate(group_layouts):
        for c, k in enumerate(layout or ""):
            kinds[g, c] = FLOAT if k == "f" else INT
    words = buf[:n - n % 8].view(np.uint64) if buf.flags.c_contiguous else np.empty(0, np.uint64)
    nexts = _newline_ends(buf, words, n)
    raw = _scan(buf, n, nexts, names, lens, group_of_type.astype(np.int64), n_groups, kinds)
    return ScanResult(raw, n_groups)
