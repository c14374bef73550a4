#!/usr/bin/env python3
"""Checks README.md, GUIDE.md, BENCHMARKS.md and scripts/README.md against the code.

Usage: scripts/check_docs.py [--lint-only] [--bin PATH] [--keep] [--no-data] [--doc FILE]...

Lint (always, a second or less):
  - README.md has at most 300 lines; no line of the documents is longer than 200 characters;
  - the documents never say "session" and keep no diary ("tried and not kept", "that day", ...);
  - an issue number appears only for a known limitation that is still open (OPEN_ISSUES);
  - every relative link points to a file that exists;
  - scripts/README.md names every file and folder in scripts/;
  - every key of config/default.toml has a row in GUIDE.md's configuration tables
    ("| `section.key` | `default` | meaning |"), its default equal to the file's, and no row
    names a key the file does not have.

Commands (unless --lint-only): every line of a fenced block in README.md and GUIDE.md that
starts with `tessera` or `cargo run` is run, in the order of the document, in a fresh
temporary directory per document that holds a link `config` to the repository's config/.
`tessera` is the release binary (target/release/tessera, or --bin); `cargo run --release --`
is mapped to the same binary. Lines ending in a backslash continue on the next line. A
command fails the check when its exit code is not 0 (or the one its marker states).
Markers, as a comment at the end of the command's line (or alone on the first line of a
fenced block, for the whole block):
  # needs: slurm   needs a Slurm cluster: never run here
  # needs: data    reads $TESSERA_DATA (../shared/data): run only when that directory exists
                   (and --no-data is not given), else skipped
  # exits: N       the command is expected to fail with exit code N (a refusal shown on purpose)
Without --bin the binary is built first (`cargo build --release -q`; a no-op when current).

Exit 0 when everything holds; 1 with each problem listed otherwise.
"""
import argparse
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time

try:
    import tomllib
except ImportError:  # Python < 3.11
    try:
        import tomli as tomllib
    except ImportError:
        sys.exit("check_docs.py needs Python >= 3.11 (tomllib) or the tomli package")

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
DOCS = ["README.md", "GUIDE.md", "BENCHMARKS.md", "scripts/README.md"]
RUN_DOCS = ["README.md", "GUIDE.md"]
MAX_README_LINES = 300
MAX_LINE_CHARS = 200
# Issues that name a known limitation still open. An issue number anywhere else in the
# documents is history and belongs in the git log. Update when one of these closes.
OPEN_ISSUES = {63, 65, 66, 67}
DIARY = [
    r"\bsessions?\b",
    r"tried and not kept",
    r"measured and not taken",
    r"\bthat day\b",
    r"\bthe same day\b",
    r"\bin progress\b",
    r"\byesterday\b",
]
COMMAND_TIMEOUT_S = 900


def read(rel):
    with open(os.path.join(ROOT, rel), encoding="utf-8") as f:
        return f.read()


def lint(problems):
    for rel in DOCS:
        path = os.path.join(ROOT, rel)
        if not os.path.isfile(path):
            problems.append(f"{rel}: missing")
            continue
        lines = read(rel).split("\n")
        if lines and lines[-1] == "":
            lines.pop()
        if rel == "README.md" and len(lines) > MAX_README_LINES:
            problems.append(f"README.md: {len(lines)} lines (at most {MAX_README_LINES})")
        in_fence = False
        for n, line in enumerate(lines, 1):
            if line.lstrip().startswith("```"):
                in_fence = not in_fence
            if len(line) > MAX_LINE_CHARS:
                problems.append(f"{rel}:{n}: {len(line)} characters (at most {MAX_LINE_CHARS})")
            for pat in DIARY:
                m = re.search(pat, line, re.IGNORECASE)
                if m:
                    problems.append(f"{rel}:{n}: diary or history wording {m.group(0)!r}")
            for m in re.finditer(r"\b[Ii]ssues? (\d+)|#(\d+)\b", line):
                num = int(m.group(1) or m.group(2))
                if in_fence and m.group(2):
                    continue  # '#' in a shell block is a comment, not an issue
                if num not in OPEN_ISSUES:
                    problems.append(
                        f"{rel}:{n}: issue {num} is not an open limitation ({sorted(OPEN_ISSUES)})"
                    )
            for m in re.finditer(r"\]\(([^)\s]+)\)", line):
                target = m.group(1).split("#")[0]
                if not target or re.match(r"[a-z]+:", target):
                    continue
                if not os.path.exists(os.path.join(os.path.dirname(path), target)):
                    problems.append(f"{rel}:{n}: link to {target}, which does not exist")
    # The scripts index names every script.
    index = read("scripts/README.md") if os.path.isfile(os.path.join(ROOT, "scripts/README.md")) else ""
    for name in sorted(os.listdir(os.path.join(ROOT, "scripts"))):
        if name in ("README.md", "__pycache__") or name.startswith("."):
            continue
        if f"`{name}" not in index:
            problems.append(f"scripts/README.md: does not name scripts/{name}")


def flatten(prefix, table):
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            yield from flatten(key, v)
        else:
            yield key, v


def check_config(problems):
    with open(os.path.join(ROOT, "config/default.toml"), "rb") as f:
        cfg = tomllib.load(f)
    keys = dict(flatten("", cfg))
    sections = set(cfg)
    guide = read("GUIDE.md") if os.path.isfile(os.path.join(ROOT, "GUIDE.md")) else ""
    rows = {}
    for n, line in enumerate(guide.split("\n"), 1):
        m = re.match(r"\|\s*`([a-z_][a-z0-9_.]*)`\s*\|\s*(.*?)\s*\|", line)
        if m and m.group(1).split(".")[0] in sections and "." in m.group(1):
            rows.setdefault(m.group(1), (n, m.group(2)))
    for key, value in keys.items():
        if key not in rows:
            problems.append(f"GUIDE.md: config key {key} (config/default.toml) has no table row")
            continue
        n, cell = rows[key]
        lit = cell.strip()
        if lit.startswith("`") and lit.endswith("`"):
            lit = lit[1:-1]
        try:
            doc_value = tomllib.loads(f"v = {lit}")["v"]
        except Exception:
            problems.append(f"GUIDE.md:{n}: default of {key} is not a TOML value: {cell!r}")
            continue
        if doc_value != value and not (
            isinstance(value, float) and isinstance(doc_value, int) and doc_value == value
        ):
            problems.append(f"GUIDE.md:{n}: {key} default {lit} but config/default.toml says {value!r}")
    for key, (n, _) in rows.items():
        if key not in keys:
            problems.append(f"GUIDE.md:{n}: row for {key}, which config/default.toml does not have")
    return len(keys)


MARK = re.compile(r"#\s*(needs|exits):\s*([A-Za-z0-9_-]+)")


def commands(rel):
    """(line number, command, {marker: value}) for each tessera / cargo run line of a fence."""
    out = []
    in_fence = False
    block_marks = {}
    first = False
    pending = None
    for n, raw in enumerate(read(rel).split("\n"), 1):
        line = raw.strip()
        if line.startswith("```"):
            in_fence = not in_fence
            block_marks, first, pending = {}, in_fence, None
            continue
        if not in_fence:
            continue
        if first and line.startswith("#"):
            block_marks = dict(MARK.findall(line))
        first = False
        if pending is not None:
            start, text = pending
            text += " " + line.rstrip("\\").strip()
            if line.endswith("\\"):
                pending = (start, text)
            else:
                pending = None
                out.append(finish(start, text, block_marks))
            continue
        if line.startswith("$ "):
            line = line[2:]
        if re.match(r"(tessera|cargo run)\b", line):
            if line.endswith("\\"):
                pending = (n, line.rstrip("\\").strip())
            else:
                out.append(finish(n, line, block_marks))
    return out


def finish(n, text, block_marks):
    marks = dict(block_marks)
    marks.update(MARK.findall(text))
    return n, text, marks


def to_shell(cmd, binary):
    b = shlex.quote(binary)
    m = re.match(r"cargo run(?: --release)?(?: --(?=\s|$))?", cmd)
    if m:
        return b + cmd[m.end():]
    return re.sub(r"^tessera\b", b, cmd)


def run_commands(binary, keep, use_data, problems, only):
    data = os.environ.get("TESSERA_DATA") or os.path.join(ROOT, "..", "shared", "data")
    have_data = use_data and os.path.isdir(data)
    env = dict(os.environ, TESSERA_DATA=os.path.abspath(data))
    totals = {"run": 0, "skipped": [], "seconds": 0.0}
    for rel in RUN_DOCS:
        if only and rel not in only:
            continue
        work = tempfile.mkdtemp(prefix="tessera-docs-")
        os.symlink(os.path.join(ROOT, "config"), os.path.join(work, "config"))
        print(f"== {rel} (in {work})", flush=True)
        for n, cmd, marks in commands(rel):
            need = marks.get("needs")
            if need and not (need == "data" and have_data):
                totals["skipped"].append(f"{rel}:{n} [needs: {need}] {cmd}")
                print(f"  skip {rel}:{n} (needs: {need})", flush=True)
                continue
            want = int(marks.get("exits", 0))
            t0 = time.time()
            try:
                p = subprocess.run(
                    ["bash", "-c", to_shell(cmd, binary)],
                    cwd=work,
                    env=env,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE,
                    text=True,
                    timeout=COMMAND_TIMEOUT_S,
                )
                code, err = p.returncode, p.stderr
            except subprocess.TimeoutExpired:
                code, err = "timeout", ""
            dt = time.time() - t0
            totals["run"] += 1
            totals["seconds"] += dt
            ok = code == want
            print(f"  {'ok  ' if ok else 'FAIL'} {dt:6.1f} s  {rel}:{n}  {cmd}", flush=True)
            if not ok:
                tail = "\n      ".join(err.strip().split("\n")[-15:])
                problems.append(f"{rel}:{n}: `{cmd}` exited {code}, expected {want}\n      {tail}")
        if keep:
            print(f"  kept {work}")
        else:
            subprocess.run(["rm", "-rf", work])
    return totals


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lint-only", action="store_true", help="line rules, wording, links, config keys")
    ap.add_argument("--bin", help="tessera binary to run (default: build target/release/tessera)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary directories")
    ap.add_argument("--no-data", action="store_true", help="skip '# needs: data' commands")
    ap.add_argument("--doc", action="append", help="run the commands of this document only")
    a = ap.parse_args()
    problems = []
    lint(problems)
    n_keys = check_config(problems)
    print(f"lint: {len(DOCS)} documents, {n_keys} configuration keys checked against GUIDE.md")
    if not a.lint_only:
        binary = a.bin
        if not binary:
            subprocess.run(["cargo", "build", "--release", "-q"], cwd=ROOT, check=True)
            target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
            binary = os.path.join(target, "release", "tessera")
        binary = os.path.abspath(binary)
        t = run_commands(binary, a.keep, not a.no_data, problems, a.doc)
        print(f"commands: {t['run']} run in {t['seconds']:.0f} s, {len(t['skipped'])} skipped")
        for s in t["skipped"]:
            print(f"  skipped {s}")
    if problems:
        print(f"\n{len(problems)} problem(s):")
        for p in problems:
            print(f"  {p}")
        return 1
    print("docs: OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
