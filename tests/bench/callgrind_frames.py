#!/usr/bin/python3
"""Per-frame instruction counts of a PD benchmark under callgrind.

Runs bench_pdt or bench_pdg (one benchmark of it) under
valgrind --tool=callgrind with collection off except inside each PD call
(tests/bench/callgrind_frame.h), one dump per call, and prints per label
(pdt, pdg, pdg-unbudgeted) the distribution of instructions per frame, the
frames over a threshold, and for the costliest frames the functions their
instructions were spent in (inclusive, from callgrind_annotate).

  /usr/bin/python3 tests/bench/callgrind_frames.py BENCH_BINARY BENCHMARK \
      [--frames N] [--out DIR] [--over MINSTR] [--top K] [--csv FILE]

Example:
  /usr/bin/python3 tests/bench/callgrind_frames.py \
      build/release/tests/bench/bench_pdg hammer-beast20k --out /tmp/cg
"""
import argparse
import glob
import os
import re
import subprocess
import sys


def read_dump(path):
    label, total = None, None
    with open(path, errors="replace") as f:
        for line in f:
            if line.startswith("desc: Trigger: Client Request: "):
                label = line.split("Client Request: ", 1)[1].strip()
            elif line.startswith("totals:") or line.startswith("summary:"):
                total = int(line.split()[1])
    return label, total


def percentile(values, q):
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))] if v else 0


def strip_args(name):
    """hapticpd::pd::(anonymous namespace)::Foo(int, double) -> ...::Foo"""
    name = name.split(":", 1)[1] if name.startswith("???:") else name
    depth, end = 0, len(name)
    for i in range(len(name) - 1, -1, -1):
        if name[i] == ")":
            depth += 1
        elif name[i] == "(":
            depth -= 1
            if depth == 0:
                end = i
                break
    name = name[:end].replace("(anonymous namespace)::", "")
    # Lambdas: name them by their enclosing function and number only.
    m = re.match(r"(?:\S+ )?(?:[\w:<>]+::)?(\w+)(?:<|\().*\{lambda\(.*\)#(\d+)\}", name)
    if m:
        return f"{m.group(1)}::{{lambda #{m.group(2)}}}"
    return name


def top_functions(path, k):
    """The pd functions with the most instructions, inclusive of their callees
    (callgrind_annotate --inclusive), below ComputePdt / ComputePdg."""
    out = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", path],
                         capture_output=True, text=True).stdout
    rows = []
    for line in out.splitlines():
        m = re.match(r"\s*([\d,]+)\s+\(\s*([\d.]+)%\)\s+(\S.*)", line)
        if not m or "hapticpd::" not in line:
            continue
        name = strip_args(m.group(3))
        if name.endswith(("::ComputePdt", "::ComputePdg", "::PdtCore", "::PdgCore", "Replay")):
            continue
        rows.append((int(m.group(1).replace(",", "")), name))
    return rows[:k]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("binary")
    ap.add_argument("benchmark")
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--out", default="callgrind-frames")
    ap.add_argument("--over", type=float, default=5.0,
                    help="list frames above this many million instructions")
    ap.add_argument("--top", type=int, default=3, help="costliest frames to break down")
    ap.add_argument("--csv", help="write label,frame,instructions rows here")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    for old in glob.glob(os.path.join(a.out, "cg.out*")):
        os.remove(old)
    cmd = ["valgrind", "--tool=callgrind", "--collect-atstart=no", "--dump-instr=no",
           "--callgrind-out-file=" + os.path.join(a.out, "cg.out"), a.binary,
           "--benchmark", a.benchmark, "--frames", str(a.frames),
           "--csv", os.path.join(a.out, "summary.csv")]
    print("running:", " ".join(cmd), file=sys.stderr)
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("valgrind failed:\n" + r.stderr[-2000:])
    per_label = {}
    files = {}
    for path in glob.glob(os.path.join(a.out, "cg.out.*")):
        label, total = read_dump(path)
        if label is None or total is None:
            continue
        name, frame = label.rsplit(" ", 1)
        per_label.setdefault(name, {})[int(frame)] = total
        files[(name, int(frame))] = path
    if not per_label:
        sys.exit("no per-frame dumps: was the benchmark built with valgrind/callgrind.h?")
    if a.csv:
        with open(a.csv, "w") as f:
            f.write("label,frame,instructions\n")
            for name, frames in sorted(per_label.items()):
                for frame, total in sorted(frames.items()):
                    f.write(f"{name},{frame},{total}\n")
    print(f"{a.benchmark}: instructions per frame (millions)")
    print(f"{'query':16}{'frames':>7}{'p50':>9}{'p99':>9}{'max':>9}{'> ' + str(a.over):>8}")
    for name, frames in sorted(per_label.items()):
        v = [t / 1e6 for t in frames.values()]
        print(f"{name:16}{len(v):7d}{percentile(v, 0.5):9.2f}{percentile(v, 0.99):9.2f}"
              f"{max(v):9.2f}{sum(1 for x in v if x > a.over):8d}")
    for name, frames in sorted(per_label.items()):
        over = sorted((f for f, t in frames.items() if t / 1e6 > a.over))
        print(f"\n{name}: frames over {a.over} M instructions: {over}")
        for frame, total in sorted(frames.items(), key=lambda x: -x[1])[:a.top]:
            print(f"  frame {frame}: {total / 1e6:.2f} M")
            for ir, fn in top_functions(files[(name, frame)], 8):
                print(f"    {100.0 * ir / total:5.1f}%  {fn[:110]}")


if __name__ == "__main__":
    main()
