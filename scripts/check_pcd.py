#!/usr/bin/env python3
"""Independent PCD reader used as an oracle for the Rust reader's tests.

    check_pcd.py FILE.pcd [FILE.pcd ...]

Prints one JSON object per file (one per line):
  points       POINTS from the header
  decoded      points actually decoded
  finite       points whose x, y, z are all finite
  sum_x/y/z    sums over finite points (float64 of the stored values)
  sum_rgb      [sum r, sum g, sum b] over all points from a packed rgb/rgba field, or null
  first/last   x, y, z of the first and last finite point
  pcdio        "agrees" / "disagrees" when ../shared/peers/pcdio.py (ascii and binary only)
               could read the file too, else "n/a"

Written separately from the Rust code: its own header parser, its own LZF decoder (pure
Python) and numpy structured dtypes for the binary layouts.
"""
import json
import math
import os
import sys

import numpy as np

TYPES = {("F", 4): "<f4", ("F", 8): "<f8",
         ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8",
         ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}


def lzf_decompress(data, out_len):
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            out += data[i:i + ctrl + 1]
            i += ctrl + 1
        else:
            length = ctrl >> 5
            if length == 7:
                length += data[i]
                i += 1
            ref = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
            i += 1
            length += 2
            if ref < 0:
                raise ValueError("LZF reference before start")
            if len(out) - ref >= length:
                out += out[ref:ref + length]
            else:
                for k in range(length):
                    out.append(out[ref + k])
    if len(out) != out_len:
        raise ValueError(f"LZF produced {len(out)} bytes, header says {out_len}")
    return bytes(out)


def read_header(raw):
    hdr, pos = {}, 0
    while True:
        end = raw.index(b"\n", pos) + 1
        line = raw[pos:end].decode("ascii").strip()
        pos = end
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        hdr[key] = vals
        if key == "DATA":
            return hdr, pos


def read(path):
    raw = open(path, "rb").read()
    hdr, pos = read_header(raw)
    names = hdr["FIELDS"]
    sizes = [int(s) for s in hdr["SIZE"]]
    types = hdr["TYPE"]
    counts = [int(c) for c in hdr.get("COUNT", ["1"] * len(names))]
    n = int(hdr["POINTS"][0])
    cols = [(f"{nm}__{k}", TYPES[(t, s)], c) for k, (nm, s, t, c) in enumerate(zip(names, sizes, types, counts))]
    dt = np.dtype([(nm, ty, (c,)) if c > 1 else (nm, ty) for nm, ty, c in cols])
    mode = hdr["DATA"][0]
    body = raw[pos:]
    if mode == "binary":
        rec = np.frombuffer(body, dtype=dt, count=n)
    elif mode == "binary_compressed":
        csize, usize = np.frombuffer(body[:8], "<u4")
        flat = lzf_decompress(body[8:8 + int(csize)], int(usize))
        rec = np.zeros(n, dtype=dt)
        off = 0
        for nm, ty, c in cols:
            width = np.dtype(ty).itemsize * c
            arr = np.frombuffer(flat[off:off + n * width], dtype=ty)
            rec[nm] = arr.reshape(n, c) if c > 1 else arr
            off += n * width
    elif mode == "ascii":
        rows = [ln.split() for ln in body.decode("ascii").splitlines() if ln.strip()][:n]
        rec = np.zeros(n, dtype=dt)
        for i, toks in enumerate(rows):
            j = 0
            for nm, ty, c in cols:
                for e in range(c):
                    tok = toks[j]
                    j += 1
                    if ty == "<f4" and nm.startswith(("rgb__", "rgba__")):
                        # keep the packed bits of a float colour exactly
                        val = np.float32(float(tok))
                    elif ty.startswith("<f"):
                        val = float(tok)
                    else:
                        val = int(float(tok)) if ("." in tok or "e" in tok.lower()) else int(tok)
                    if c > 1:
                        rec[nm][i][e] = val
                    else:
                        rec[nm][i] = val
    else:
        raise SystemExit(f"{path}: DATA {mode} unsupported")
    return names, cols, rec, n, mode


def column(names, cols, rec, name):
    k = names.index(name)
    return rec[cols[k][0]]


def summarise(path):
    names, cols, rec, n, mode = read(path)
    x, y, z = (column(names, cols, rec, a).astype(np.float64) for a in "xyz")
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    out = {"file": os.path.basename(path), "points": n, "decoded": int(len(rec)),
           "finite": int(ok.sum()),
           "sum_x": float(x[ok].sum()), "sum_y": float(y[ok].sum()), "sum_z": float(z[ok].sum()),
           "sum_rgb": None}
    idx = np.flatnonzero(ok)
    if len(idx):
        out["first"] = [float(x[idx[0]]), float(y[idx[0]]), float(z[idx[0]])]
        out["last"] = [float(x[idx[-1]]), float(y[idx[-1]]), float(z[idx[-1]])]
    for cname in ("rgb", "rgba"):
        if cname in names:
            bits = np.ascontiguousarray(column(names, cols, rec, cname)).view("<u4").astype(np.int64)
            out["sum_rgb"] = [int(((bits >> 16) & 255).sum()), int(((bits >> 8) & 255).sum()),
                              int((bits & 255).sum())]
            break
    out["pcdio"] = cross_check_pcdio(path, mode, x, y, z)
    return out


def cross_check_pcdio(path, mode, x, y, z):
    if mode not in ("ascii", "binary"):
        return "n/a"
    peers = os.environ.get("TESSERA_PEERS", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "peers"))
    sys.path.insert(0, peers)
    try:
        import pcdio  # noqa: E402
    except ImportError:
        return "n/a"
    r = pcdio.read_pcd(path)
    same = all(np.array_equal(np.asarray(r[a], np.float64), b, equal_nan=True)
               for a, b in zip("xyz", (x, y, z)))
    return "agrees" if same else "disagrees"


def main():
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    for p in sys.argv[1:]:
        s = summarise(p)
        assert all(math.isfinite(s[k]) for k in ("sum_x", "sum_y", "sum_z"))
        print(json.dumps(s))


if __name__ == "__main__":
    main()
