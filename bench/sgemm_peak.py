"""The machine's sgemm peak that the grid benchmark's "% of peak" is read against: torch's
float32 matrix product on square matrices, 1 and 2 threads (run with the bench venv's python).

    bench-out/torch-venv/bin/python bench/sgemm_peak.py [--threads T]

bench_grid.py runs it before and after its peers, at its own thread count.
"""
import argparse
import time

import torch

ap = argparse.ArgumentParser()
ap.add_argument("--threads", type=int, help="only this thread count (default: 1 and 2)")
args = ap.parse_args()
for threads in [args.threads] if args.threads else (1, 2):
    torch.set_num_threads(threads)
    for n in (512, 1024, 2048):
        a, b = torch.randn(n, n), torch.randn(n, n)
        for _ in range(3):
            a @ b
        reps = max(3, int(2e10 / (2 * n**3)))
        t0 = time.perf_counter()
        for _ in range(reps):
            a @ b
        dt = time.perf_counter() - t0
        print(f"threads {threads} n {n}: {2 * n**3 * reps / dt / 1e9:.1f} GFLOP/s")
