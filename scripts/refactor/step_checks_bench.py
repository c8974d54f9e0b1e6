"""Process time of one tensegrity_gym.step call (prism3, semi-implicit Euler, one step), B = 1, 64,
4096; best of 5 windows of 0.2 s. Run with two checkouts, alternating:
    PYTHONPATH=<checkout> NUMBA_NUM_THREADS=1 taskset -c 0 python scripts/refactor/step_checks_bench.py"""
import time, numpy as np, tensegrity_gym as tg
m = tg.compile_model(tg.prism(3)); 
for B in (1, 64, 4096):
    st = tg.initial_state(m, B)
    tg.step(m, st, 1e-3)
    best = 1e9
    for _ in range(5):
        t0 = time.process_time(); n = 0
        while time.process_time() - t0 < 0.2:
            tg.step(m, st, 1e-3); n += 1
        best = min(best, (time.process_time() - t0) / n)
    print(f"B={B} {best*1e6:.2f} us")
