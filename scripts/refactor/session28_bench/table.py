"""The before/after speed table of run.sh's outputs (best of rounds 3 and 4 per row).

    python scripts/refactor/session28_bench/table.py [results/refactor/session28]
"""
import csv, glob, os, re, sys
HERE = os.path.dirname(os.path.abspath(__file__))
B = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "..", "..", "..", "results", "refactor", "session28")
def kern(side):
    best = {}
    for f in glob.glob(f"{B}/{side}_kern_[34].txt"):
        for line in open(f):
            m = re.match(r"(\S+)\s+(\S+)\s+B=(\d+)\s+([\d.]+) us/step", line)
            if m:
                k = (m[1], m[2], int(m[3])); best[k] = min(best.get(k, 1e9), float(m[4]))
    return best
def overhead(side):
    best = {}
    for f in glob.glob(f"{B}/{side}_overhead_[34].txt"):
        for line in open(f):
            m = re.match(r"\| (\w+) \| \d+ \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|", line)
            if m:
                best[m[1]] = min(best.get(m[1], (1e9, 0, 0)), (float(m[2]), float(m[3]), float(m[4])))
    return best
def envs(side):
    best = {}
    for f in glob.glob(f"{B}/{side}_envs_[34].csv"):
        rows = list(csv.DictReader(open(f)))
        for r in rows:
            k = (r["env_id"], r["method"], r["n_envs"])
            val = float(r["env_steps_per_s"]) if r["status"] == "ok" else None
            if val is not None:
                best[k] = max(best.get(k, 0), val)
    return best
kb, km = kern("base"), kern("main")
print("| scene | integrator | B | before (us/step) | after (us/step) | after / before |\n|---|---|---:|---:|---:|---:|")
for k in sorted(kb):
    if k in km: print(f"| {k[0]} | {k[1]} | {k[2]} | {kb[k]:.3f} | {km[k]:.3f} | {km[k]/kb[k]:.2f} |")
ob, om = overhead("base"), overhead("main")
print("\n| shape single-env step() | before step (us) | after step (us) | after / before |\n|---|---:|---:|---:|")
for k in ob:
    if k in om: print(f"| {k} | {ob[k][0]:.1f} | {om[k][0]:.1f} | {om[k][0]/ob[k][0]:.2f} |")
eb, em = envs("base"), envs("main")
print("\n| env | method | N | before (env-steps/s) | after (env-steps/s) | after / before (time) |\n|---|---|---:|---:|---:|---:|")
for k in sorted(eb, key=str):
    if k in em: print(f"| {k[0]} | {k[1]} | {k[2]} | {eb[k]:,.0f} | {em[k]:,.0f} | {eb[k]/em[k]:.2f} |")
