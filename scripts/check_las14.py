#!/usr/bin/env python3
"""Validates LAS/LAZ files written by tessera against LAS 1.4 R15, with an independent reader.

    python3 scripts/check_las14.py FILE... [--dir DIR]

The header is parsed byte by byte here; the points are read with laspy (+ lazrs for LAZ), and
every header field that describes the points is compared with what the points are: counts
(64-bit and legacy), points by return, bounds, record length, the extra-bytes record. The CRS
rules of R15: formats 6-10 set the WKT bit and carry an OGC WKT record (2112), never GeoTIFF
keys; a WKT record means the WKT bit is set. Prints one line per file; exit 1 on any
violation, 2 on a usage error.
"""
import os
import struct
import sys

import numpy as np

try:
    import laspy
except ImportError:  # pragma: no cover
    print("laspy is needed: pip install laspy lazrs", file=sys.stderr)
    sys.exit(2)

BASE_RECORD = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
CRS_GEOTIFF = {34735, 34736, 34737}
WKT_RECORD = 2112
EB_RECORD = 4
EB_SIZES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 8, 8: 8, 9: 4, 10: 8}


def header_fields(raw):
    h = {}
    h["signature"] = raw[0:4]
    h["global_encoding"] = struct.unpack_from("<H", raw, 6)[0]
    h["version"] = (raw[24], raw[25])
    h["header_size"] = struct.unpack_from("<H", raw, 94)[0]
    h["offset_to_points"] = struct.unpack_from("<I", raw, 96)[0]
    h["n_vlrs"] = struct.unpack_from("<I", raw, 100)[0]
    h["format_byte"] = raw[104]
    h["record_len"] = struct.unpack_from("<H", raw, 105)[0]
    h["legacy_count"] = struct.unpack_from("<I", raw, 107)[0]
    h["legacy_by_return"] = struct.unpack_from("<5I", raw, 111)
    h["scale"] = struct.unpack_from("<3d", raw, 131)
    h["offset"] = struct.unpack_from("<3d", raw, 155)
    mx, mn_x, my, mn_y, mz, mn_z = struct.unpack_from("<6d", raw, 179)
    h["max"] = (mx, my, mz)
    h["min"] = (mn_x, mn_y, mn_z)
    h["evlr_start"], h["n_evlrs"], h["count"] = struct.unpack_from("<QIQ", raw, 235)
    h["by_return"] = struct.unpack_from("<15Q", raw, 255)
    return h


def vlrs_of(raw, h):
    out, pos = [], h["header_size"]
    for _ in range(h["n_vlrs"]):
        user = raw[pos + 2:pos + 18].split(b"\0")[0].decode("ascii", "replace")
        rid, length = struct.unpack_from("<HH", raw, pos + 18)
        out.append((user, rid, raw[pos + 54:pos + 54 + length]))
        pos += 54 + length
    return out, pos


def evlrs_of(path, h, size):
    out = []
    if h["n_evlrs"] == 0:
        return out
    with open(path, "rb") as f:
        pos = h["evlr_start"]
        for _ in range(h["n_evlrs"]):
            f.seek(pos)
            e = f.read(60)
            user = e[2:18].split(b"\0")[0].decode("ascii", "replace")
            rid = struct.unpack_from("<H", e, 18)[0]
            length = struct.unpack_from("<Q", e, 20)[0]
            data = f.read(min(length, 1 << 20))
            out.append((user, rid, data))
            pos += 60 + length
    return out


def balanced(wkt):
    depth = 0
    quoted = False
    for c in wkt:
        if c == '"':
            quoted = not quoted
        elif not quoted and c in "[(":
            depth += 1
        elif not quoted and c in "])":
            depth -= 1
            if depth < 0:
                return False
    return depth == 0 and not quoted


def check(path):
    problems = []
    bad = problems.append
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(min(size, 1 << 20))
    if len(head) < 375:
        return [f"{len(head)} bytes: shorter than a LAS 1.4 header"]
    h = header_fields(head)
    if h["signature"] != b"LASF":
        return ["not a LAS file (signature)"]
    if h["version"] != (1, 4):
        bad(f"version {h['version'][0]}.{h['version'][1]}, not 1.4")
    if h["header_size"] != 375:
        bad(f"header size {h['header_size']}, not 375")
    fmt = h["format_byte"] & 0x3F
    compressed = bool(h["format_byte"] & 0x80)
    if fmt not in BASE_RECORD:
        return problems + [f"point format {fmt} is not 0-10"]
    if h["record_len"] < BASE_RECORD[fmt]:
        bad(f"record length {h['record_len']} below the {BASE_RECORD[fmt]} of format {fmt}")
    extra = h["record_len"] - BASE_RECORD[fmt]
    vlrs, vlr_end = vlrs_of(head, h)
    if vlr_end > h["offset_to_points"]:
        bad(f"VLRs end at byte {vlr_end}, past the point data offset {h['offset_to_points']}")
    evlrs = evlrs_of(path, h, size)
    records = vlrs + evlrs
    if h["n_evlrs"] and not (h["offset_to_points"] <= h["evlr_start"] < size):
        bad(f"first EVLR at byte {h['evlr_start']}, outside the file")
    ge = h["global_encoding"]
    wkt_bit = bool(ge & 16)
    if ge & 6 == 6:
        bad("waveform data marked both internal and external")
    if ge & ~0x1F:
        bad(f"reserved global-encoding bits set ({ge:#06x})")
    proj = [(u, r, d) for (u, r, d) in records if u == "LASF_Projection"]
    wkts = [d for (_, r, d) in proj if r == WKT_RECORD]
    geotiff = [r for (_, r, _) in proj if r in CRS_GEOTIFF]
    if fmt >= 6:
        if not wkt_bit:
            bad(f"format {fmt} without the WKT bit")
        if geotiff:
            bad(f"format {fmt} carries GeoTIFF CRS records {sorted(set(geotiff))} (R15: WKT only)")
    if wkts:
        if not wkt_bit:
            bad("an OGC WKT record without the WKT bit")
        text = wkts[0].rstrip(b"\0").decode("utf-8", "replace").strip()
        if not text or not balanced(text) or not text.split("[")[0].isupper():
            bad(f"OGC WKT record is not WKT: {text[:60]!r}")
    elif wkt_bit and geotiff:
        bad("WKT bit set, GeoTIFF records and no OGC WKT record")
    if any(s <= 0 or not np.isfinite(s) for s in h["scale"]):
        bad(f"scale factors {h['scale']}")
    if compressed and not any(u == "laszip encoded" and r == 22204 for (u, r, _) in vlrs):
        bad("compressed point format without a LASzip VLR")
    ebs = [d for (u, r, d) in records if u == "LASF_Spec" and r == EB_RECORD]
    if ebs:
        total = 0
        for k in range(len(ebs[0]) // 192):
            d = ebs[0][k * 192:(k + 1) * 192]
            dtype, opts = d[2], d[3]
            total += EB_SIZES.get(dtype, opts if dtype == 0 else 0)
        if total > extra:
            bad(f"extra-bytes record describes {total} bytes, records have {extra}")
    elif extra:
        bad(f"{extra} extra bytes per record but no extra-bytes record")
    if not compressed:
        end = h["offset_to_points"] + h["count"] * h["record_len"]
        limit = h["evlr_start"] if h["n_evlrs"] else size
        if end != limit:
            bad(f"point data ends at byte {end}, the file (or its EVLRs) at {limit}")

    las = laspy.read(path)
    n = len(las.points)
    if n != h["count"]:
        bad(f"header count {h['count']}, {n} points in the file")
    legacy_ok = fmt < 6 and n <= 0xFFFFFFFF
    want_legacy = n if legacy_ok else 0
    if h["legacy_count"] != want_legacy:
        bad(f"legacy point count {h['legacy_count']}, should be {want_legacy}")
    rn = np.asarray(las.return_number)
    hist = [int(np.count_nonzero(rn == r)) for r in range(1, 16)]
    if list(h["by_return"]) != hist:
        bad(f"points by return {list(h['by_return'])[:5]}..., counted {hist[:5]}...")
    want_legacy_ret = hist[:5] if legacy_ok else [0] * 5
    if list(h["legacy_by_return"]) != want_legacy_ret:
        bad(f"legacy points by return {list(h['legacy_by_return'])}, should be {want_legacy_ret}")
    if n:
        for axis, k in (("x", 0), ("y", 1), ("z", 2)):
            v = np.asarray(getattr(las, axis))
            tol = h["scale"][k] * 0.5 + 1e-9
            if abs(v.min() - h["min"][k]) > tol or abs(v.max() - h["max"][k]) > tol:
                bad(
                    f"{axis} bounds {h['min'][k]}..{h['max'][k]}, points {v.min()}..{v.max()}"
                )
        if fmt < 6 and int(np.asarray(las.classification).max()) > 31:
            bad("class codes above 31 in a legacy point format")
    return problems


def main(argv):
    paths = []
    args = iter(argv)
    for a in args:
        if a == "--dir":
            d = next(args, None)
            if d is None:
                print("--dir needs a directory", file=sys.stderr)
                return 2
            paths += sorted(
                os.path.join(d, f) for f in os.listdir(d) if f.lower().endswith((".las", ".laz"))
            )
        else:
            paths.append(a)
    if not paths:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    failed = 0
    for p in paths:
        try:
            problems = check(p)
        except Exception as e:  # an unreadable file is a violation, not a crash
            problems = [f"cannot be read: {e}"]
        if problems:
            failed += 1
            print(f"FAIL {p}")
            for m in problems:
                print(f"  - {m}")
        else:
            print(f"ok   {p}")
    print(f"{len(paths) - failed}/{len(paths)} files valid LAS 1.4")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
