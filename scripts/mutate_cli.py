#!/usr/bin/env python3
"""Black-box mutation test of the tessera CLI on real files (issue 23).

Mutates small real inputs (LAS, LAZ, MCAP, PCD) as a hostile user would — bit flips, byte
overwrites, truncation, and header fields set to extreme values (point counts, offsets, record
lengths, VLR lengths, EVLR offsets, scales, chunk tables, MCAP record lengths, PCD header
lines) — and runs `tessera info`, a pass-through `tessera run`, `tessera thin` and `tessera
eval ground` on each mutant under an address-space limit and a timeout.

A run passes when it exits 0, or exits non-zero with an "error:" line. It fails (a finding)
when it is killed by a signal, panics (exit 101), aborts ("memory allocation of"), times out,
uses more memory than the limit allows, or leaves `*.tmp` / staging files in its output
directory (`thin`, `eval`: the mutant's directory) after a failure.

Usage: scripts/mutate_cli.py [--bin target/release/tessera] [--seconds 300] [--seed 1]
                             [--data ../shared/data] [--keep DIR]
Exit code 1 when any finding was made; findings are copied to --keep (default
/tmp/tessera-mutants) with the command that failed.
"""

import argparse
import os
import random
import resource
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time

MEM_LIMIT = 2 << 30  # bytes of address space per run (2 GiB)


def inputs(data):
    """Small real files of every format tessera reads."""
    want = [
        ("pdal-autzen-samples", "sample_c.las"),
        ("pdal-autzen-samples", "interesting.las"),
        ("pdal-autzen-samples", "autzen_trim.laz"),  # feet, OGC WKT + GeoTIFF keys
        ("isprs-filtertest", "samp24-utm.laz"),
        ("mcap-ouster-ros1", "ouster_os1_ros1profile.mcap"),
        ("pcl-tutorials", "min_cut_segmentation_tutorial.pcd"),
    ]
    out = []
    for d, f in want:
        p = os.path.join(data, d, f)
        if os.path.exists(p):
            out.append(p)
    return out


def layered_laz(path):
    """A LAS 1.4 format-7 LAZ (layered chunks) whose GPS times interleave four sequences,
    so mutants reach the layered decoders and the GPS sequence switches; needs laspy."""
    try:
        import laspy
        import numpy as np
    except ImportError:
        return None
    rng = np.random.default_rng(7)
    n = 60_000
    h = laspy.LasHeader(point_format=7, version="1.4")
    h.scales = [0.01] * 3
    h.offsets = [0.0] * 3
    las = laspy.LasData(h)
    las.x = rng.uniform(0, 50, n)
    las.y = rng.uniform(0, 50, n)
    las.z = rng.uniform(0, 5, n)
    las.gps_time = 1e8 * (rng.integers(0, 4, n) + 1) + np.arange(n) * 1e-5
    las.red = rng.integers(0, 65535, n)
    las.write(path, laz_backend=laspy.LazBackend.Lazrs)
    return path


def put(buf, off, fmt, value):
    size = struct.calcsize(fmt)
    if 0 <= off and off + size <= len(buf):
        buf[off:off + size] = struct.pack(fmt, value)


EXTREMES = [0, 1, 0x7F, 0xFF, 0xFFFF, 0x7FFFFFFF, 0xFFFFFFFF, 0x7FFFFFFFFFFFFFFF,
            0xFFFFFFFFFFFFFFFF, 1 << 31, 1 << 40]


def extreme(fmt, rng):
    bits = 8 * struct.calcsize(fmt)
    v = rng.choice(EXTREMES) & ((1 << bits) - 1)
    if fmt.endswith("d"):
        return rng.choice([0.0, -0.0, 1e-300, 1e300, float("nan"), float("inf"), -1.0])
    if fmt[-1] in "bhiq":
        v -= (1 << bits) if v >= (1 << (bits - 1)) else 0
    return v


# LAS 1.4 header fields (offset, struct format).
LAS_FIELDS = [(94, "<H"), (96, "<I"), (100, "<I"), (104, "<B"), (105, "<H"), (107, "<I"),
              (131, "<d"), (139, "<d"), (147, "<d"), (155, "<d"), (163, "<d"), (171, "<d"),
              (179, "<d"), (187, "<d"), (195, "<d"), (203, "<d"), (211, "<d"), (219, "<d"),
              (227, "<Q"), (235, "<Q"), (243, "<I"), (247, "<Q"), (255, "<Q")]


def las_targets(buf):
    """Offsets of VLR length fields and, for LAZ, the chunk table pointer."""
    t = []
    if len(buf) < 227 or buf[:4] != b"LASF":
        return t
    hsize = struct.unpack_from("<H", buf, 94)[0]
    nvlr = struct.unpack_from("<I", buf, 100)[0]
    pos = hsize
    for _ in range(min(nvlr, 64)):
        if pos + 54 > len(buf):
            break
        t.append((pos + 20, "<H"))  # record length after header
        t.append((pos + 18, "<H"))  # record id
        length = struct.unpack_from("<H", buf, pos + 20)[0]
        user = buf[pos + 2:pos + 18]
        if user.startswith(b"laszip encoded") and pos + 54 + 34 <= len(buf):
            d = pos + 54
            for o, f in [(0, "<H"), (2, "<H"), (12, "<I"), (16, "<q"), (24, "<q"),
                         (32, "<H")]:
                t.append((d + o, f))
            n = struct.unpack_from("<H", buf, d + 32)[0]
            for k in range(min(n, 16)):
                t += [(d + 34 + 6 * k, "<H"), (d + 36 + 6 * k, "<H"), (d + 38 + 6 * k, "<H")]
        pos += 54 + length
    offset = struct.unpack_from("<I", buf, 96)[0]
    t.append((offset, "<q"))  # LAZ chunk table offset
    return t


def mcap_targets(buf):
    """Offsets of record length fields of the first records."""
    t = []
    pos = 8
    for _ in range(200):
        if pos + 9 > len(buf):
            break
        t.append((pos + 1, "<Q"))
        length = struct.unpack_from("<Q", buf, pos + 1)[0]
        op = buf[pos]
        if op == 0x06 and pos + 9 + 40 <= len(buf):  # chunk: sizes and compression
            t += [(pos + 9 + 16, "<Q"), (pos + 9 + 28, "<I")]
        pos += 9 + length
    # The footer's summary offsets, at the end.
    if len(buf) > 40:
        t += [(len(buf) - 8 - 20, "<Q"), (len(buf) - 8 - 12, "<Q")]
    return t


def mutate_pcd(buf, rng):
    text = bytes(buf)
    head_end = text.find(b"\nDATA")
    if head_end < 0:
        return None
    lines = text[:head_end].split(b"\n")
    k = rng.randrange(len(lines))
    key = lines[k].split(b" ")[0]
    vals = [b"0", b"-1", b"4294967295", b"99999999999", b"1e308", b"x", b""]
    if key in (b"WIDTH", b"HEIGHT", b"POINTS"):
        lines[k] = key + b" " + rng.choice(vals)
    elif key in (b"SIZE", b"COUNT"):
        parts = lines[k].split(b" ")
        if len(parts) > 1:
            parts[rng.randrange(1, len(parts))] = rng.choice(vals + [b"3", b"16"])
            lines[k] = b" ".join(parts)
    elif key == b"TYPE":
        parts = lines[k].split(b" ")
        if len(parts) > 1:
            parts[rng.randrange(1, len(parts))] = rng.choice([b"X", b"F", b"U", b"I"])
            lines[k] = b" ".join(parts)
    elif key == b"FIELDS" and rng.random() < 0.5:
        lines[k] = lines[k] + b" extra"
    else:
        return None
    rest = text[head_end:]
    if rng.random() < 0.2:
        rest = rest.replace(b"binary_compressed", b"binary", 1)
    return bytearray(b"\n".join(lines) + rest)


def mutate(buf, path, rng):
    b = bytearray(buf)
    kind = rng.random()
    targets = []
    if path.endswith((".las", ".laz")):
        targets = LAS_FIELDS + las_targets(b)
    elif path.endswith(".mcap"):
        targets = mcap_targets(b)
    if path.endswith(".pcd") and kind < 0.4:
        m = mutate_pcd(b, rng)
        if m is not None:
            return m, "pcd header"
    if targets and kind < 0.5:
        off, fmt = rng.choice(targets)
        put(b, off, fmt, extreme(fmt, rng))
        return b, f"field@{off}{fmt}"
    if kind < 0.7:
        n = rng.randrange(1, 9)
        head = min(len(b), 4096)
        for _ in range(n):
            i = rng.randrange(head) if rng.random() < 0.7 else rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        return b, f"{n} bit flips"
    if kind < 0.85:
        cut = rng.randrange(len(b))
        return b[:cut], f"truncated at {cut}"
    i = rng.randrange(len(b))
    n = rng.randrange(1, 16)
    b[i:i + n] = bytes(rng.randrange(256) for _ in range(n))
    return b, f"{n} random bytes at {i}"


def limit():
    resource.setrlimit(resource.RLIMIT_AS, (MEM_LIMIT, MEM_LIMIT))
    os.setsid()


def run(cmd, timeout):
    try:
        p = subprocess.run(cmd, capture_output=True, timeout=timeout, preexec_fn=limit)
        return p.returncode, p.stderr.decode("utf-8", "replace")
    except subprocess.TimeoutExpired:
        return "timeout", ""


def leftovers(out):
    bad = []
    for root, dirs, files in os.walk(out):
        for f in files + dirs:
            # Temporary files, or a run's work directory (spill files, decoded MCAP parts).
            if ".tmp" in f or f.startswith(".tessera-work-"):
                bad.append(os.path.join(root, f))
    return bad


def verdict(rc, err, out=None):
    if rc == "timeout":
        return "timeout"
    if isinstance(rc, int) and rc < 0:
        return f"killed by signal {-rc}"
    if rc == 101 or (rc not in (1, 2) and "panicked at" in err):
        return "panic"
    if "memory allocation of" in err:
        return "allocation abort"
    if rc not in (0, 1, 2):
        return f"exit code {rc}"
    if rc != 0 and "error" not in err.lower():
        return "failure without an error message"
    if out is not None and rc != 0:
        left = leftovers(out)
        if left:
            return f"left behind: {left[:3]}"
    return None


def main():
    ap = argparse.ArgumentParser()
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--bin", default=os.path.join(here, "..", "target", "release", "tessera"))
    ap.add_argument("--seconds", type=float, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--data", default=os.environ.get("TESSERA_DATA",
                                                     os.path.join(here, "..", "..", "shared", "data")))
    ap.add_argument("--keep", default="/tmp/tessera-mutants")
    ap.add_argument("--timeout", type=float, default=60)
    a = ap.parse_args()
    rng = random.Random(a.seed)
    files = inputs(a.data)
    os.makedirs(a.keep, exist_ok=True)
    layered = layered_laz(os.path.join(a.keep, "layered7.laz"))
    if layered:
        files.append(layered)
    if not files:
        print(f"no inputs under {a.data}", file=sys.stderr)
        return 2
    originals = {f: open(f, "rb").read() for f in files}
    t_end = time.time() + a.seconds
    runs = 0
    findings = []
    by_kind = {}
    while time.time() < t_end:
        src = rng.choice(files)
        data, how = mutate(originals[src], src, rng)
        with tempfile.TemporaryDirectory(prefix="tessera-mut-") as d:
            name = os.path.join(d, "m" + os.path.splitext(src)[1])
            with open(name, "wb") as f:
                f.write(data)
            out = os.path.join(d, "out")
            # info, a pass-through run, thin (a file written through a temporary file) and
            # eval (the file as reference and result): failures must leave no temporary file.
            cmds = [([a.bin, "info", name, "-q"], None),
                    ([a.bin, "run", name, "--out", out, "-q", "--set",
                      'stages.run=["stats"]', "--set", "pipeline.threads=2"], out),
                    ([a.bin, "thin", "-q", "--spacing", "0.2", name,
                      os.path.join(d, "thin.laz")], d),
                    ([a.bin, "eval", "ground", "-q", "--reference", name, "--result", name], d)]
            for cmd, where in cmds:
                rc, err = run(cmd, a.timeout)
                runs += 1
                v = verdict(rc, err, where)
                if v:
                    k = len(findings)
                    keep = os.path.join(a.keep, f"finding{k:04d}{os.path.splitext(src)[1]}")
                    shutil.copy(name, keep)
                    line = err.strip().splitlines()
                    msg = next((l for l in line if "panicked" in l or "memory allocation" in l),
                               line[-1] if line else "")
                    findings.append((v, os.path.basename(src), how, cmd[1], keep, msg[:200]))
                    by_kind[v.split(":")[0]] = by_kind.get(v.split(":")[0], 0) + 1
                    print(f"FINDING {v}: {os.path.basename(src)} ({how}), tessera {cmd[1]}: "
                          f"{msg[:200]} -> {keep}", flush=True)
    print(f"{runs} runs on {len(files)} inputs, {len(findings)} findings {by_kind}")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
