#!/usr/bin/env python3
"""List Rust functions of >= N lines in product code (crates/*/src, without tests/, benches/,
examples/ or a trailing #[cfg(test)] module): a brace counter, not a parser.

Usage: long-functions.py [N=150] [ROOT=crates] [--max K]
With --max K it exits 1 when more than K functions are listed (issue 23: at most 3 product
functions of 150+ lines; .ci/run uses it as a gate)."""
import re, sys, pathlib
args = sys.argv[1:]
limit = None
if "--max" in args:
    i = args.index("--max")
    limit = int(args[i + 1])
    del args[i:i + 2]
N = int(args[0]) if args else 150
root = pathlib.Path(args[1] if len(args) > 1 else "crates")
found = 0
fn_re = re.compile(r'^(\s*)(pub(\([^)]*\))?\s+)?(const\s+)?(async\s+)?(unsafe\s+)?fn\s+(\w+)')
for p in sorted(root.rglob("*.rs")):
    s = str(p)
    if "/tests/" in s or "/benches/" in s or s.endswith("tests.rs") or "/examples/" in s:
        continue
    lines = p.read_text().splitlines()
    # cut at #[cfg(test)]
    for i, l in enumerate(lines):
        if l.strip() == "#[cfg(test)]" and i + 1 < len(lines) and re.match(r'\s*mod\s', lines[i+1]):
            lines = lines[:i]; break
    i = 0
    while i < len(lines):
        m = fn_re.match(lines[i])
        if m:
            depth = 0; started = False; j = i
            while j < len(lines):
                depth += lines[j].count("{") - lines[j].count("}")
                if "{" in lines[j]: started = True
                if started and depth <= 0: break
                if not started and lines[j].rstrip().endswith(";"): break
                j += 1
            n = j - i + 1
            if n >= N:
                print(f"{n:5d} {s}:{i+1} {m.group(7)}")
                found += 1
            i = j + 1 if started else i + 1
        else:
            i += 1
if limit is not None and found > limit:
    print(f"{found} product functions of {N}+ lines, at most {limit} allowed", file=sys.stderr)
    sys.exit(1)
