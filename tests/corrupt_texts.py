"""Trace-text inputs that once crashed a reader or broke an invariant, minimized by the fuzzer
(``tests/fuzzing.py``) and replayed by ``tests/test_fuzz_parsers.py``. Kept as byte strings, not as
trace files: each is a line or two of the trace format, written to a temporary file to replay."""

CORRUPT_TEXTS: dict[str, bytes] = {
    'txt-empty-gets-messages-of-next-file': b'',
    'txt-float32-overflow-bias': b'5\tTYPE_GYROSCOPE_UNCALIBRATED\t1\t2\t3\t0\t-1e39\t0\t3\n',
    'txt-float32-overflow-value': b'0\tTYPE_MAGNETIC_FIELD\t4\t4e38\t6\t3',
    'txt-header-end-time-30-digits': b'#\tendTime:999999999999999999999999999999\n5\tTYPE_WAYPOINT\t1\t2\n',
    'txt-header-start-time-19-digits': b'#startTime:9999999999999999999',
    'txt-hex-integer-fast-vs-slow-path': b'5\tTYPE_ACCELEROMETER\t1\t2\t3\t0x3\n',
    'txt-int64-min-accuracy': b'5\tTYPE_ACCELEROMETER\t1\t2\t3\t-9223372036854775808\n',
    'txt-int64-min-last-seen': b'5\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t-50\t2412\t-9223372036854775808\n',
    'txt-integer-beyond-2-53-reason': b'5\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t-50\t2412\t9007199254740993\n',
    'txt-messages-of-next-file': b'5\tTYPE_WIFI\tssid\t00:11:22:33:44:55\t-50\n',
    'txt-nan-parenthesized': b'5\tTYPE_WAYPOINT\tnan(1)\t2\n',
    'txt-nul-after-documented-type': b'5\tTYPE_ACCELEROMETER\x00\t1\t2\t3\t3\n6\tTYPE_ACCELEROMETER\t1\t2\t3\t3\n',
    'txt-nul-after-wifi-type': b'5\tTYPE_WIFI\x00',
}
