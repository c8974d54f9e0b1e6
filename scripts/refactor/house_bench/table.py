"""Before/after table from the interleaved runs: the better (faster) of the two rounds per row."""
import glob
import os
import re
import sys

OUT = os.environ.get("OUT", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "results", "refactor", "house_bench"))
def best(side, kind, parse):
    rows = {}
    for f in sorted(glob.glob(f"{OUT}/{side}_{kind}_*.txt")):
        for k, v, better in parse(open(f).read()):
            if k not in rows or (v > rows[k] if better == "high" else v < rows[k]):
                rows[k] = v
    return rows
def dyn(text):
    for m in re.finditer(r"^(\S+)\s+(semi_implicit_euler|rk4)\s+(\d+) \|\s+([\d.]+)", text, re.M):
        yield f"dynamics {m.group(1)} {m.group(2)} B={m.group(3)} (us/step)", float(m.group(4)), "low"
    names = {"integrators.step (numba)": "public step", "physics.step": "public step",
             "_kernels.step_inplace": "kernel step_inplace", "numba step_inplace": "kernel step_inplace"}
    for m in re.finditer(r"^  (semi_implicit_euler|rk4)\s+(.+?)\s+([\d.]+) us", text, re.M):
        n = names.get(m.group(2).strip())
        if n: yield f"entry B=1 {m.group(1)} {n} (us)", float(m.group(3)), "low"
def over(text):
    for m in re.finditer(r"^\| (rest_length|force_density) \| \d \| ([\d.]+) \|", text, re.M):
        yield f"shape single env step() {m.group(1)} (us)", float(m.group(2)), "low"
def envs(text):
    env = None
    for line in text.splitlines():
        m = re.match(r"## (Tensegrity\S+)", line)
        if m: env = m.group(1)
        m = re.match(r"\s+(\d+) batched\s+([\d,]+)", line)
        if m and env: yield f"{env} batched N={m.group(1)} (env-steps/s)", float(m.group(2).replace(",", "")), "high"
def kern(text):
    for m in re.finditer(r"^(\S+)\s+(semi_implicit_euler|rk4)\s+B=(\d+)\s+([\d.]+) us/step", text, re.M):
        yield f"kernel {m.group(1)} {m.group(2)} B={m.group(3)}, 10 steps per call, long window (us per step of the whole batch)", float(m.group(4)), "low"


def gpu(text):
    for m in re.finditer(r"^(\S+)\s+B=\s+(\d+)\s+numba f64\s+([\d,]+)\s+torch f32\s+([\d,]+)", text, re.M):
        yield f"bench_gpu {m.group(1)} B={m.group(2)} numba f64 (env-steps/s)", float(m.group(3).replace(",", "")), "high"
        yield f"bench_gpu {m.group(1)} B={m.group(2)} torch f32 (env-steps/s)", float(m.group(4).replace(",", "")), "high"
print("| row | before | after | after/before (time ratio: >1 slower) |\n|---|---:|---:|---:|")
worst = []
for kind, parse in (("kern", kern), ("dyn", dyn), ("overhead", over), ("envs", envs), ("gpu", gpu)):
    b, a = best("base", kind, parse), best("integ", kind, parse)
    for k in b:
        if k in a:
            hi = "env-steps/s" in k
            r = (b[k] / a[k]) if hi else (a[k] / b[k])
            worst.append((r, k))
            print(f"| {k} | {b[k]:,.4g} | {a[k]:,.4g} | {r:.2f} |")
worst.sort(reverse=True)
print("\nslowest rows (time ratio):", [(round(r, 2), k) for r, k in worst[:5]], file=sys.stderr)
