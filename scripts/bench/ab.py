#!/usr/bin/env python3
"""Interleaved A/B timing of two whole commands: `scripts/bench/ab.py "CMD_A" "CMD_B" [PAIRS=30]`.
Runs A then B, PAIRS times, and prints both medians and their ratio (the machine is shared and noisy:
interleaving exposes both commands to the same load)."""
import subprocess, time, sys, statistics
a, b = sys.argv[1], sys.argv[2]; n = int(sys.argv[3]) if len(sys.argv) > 3 else 30
ta, tb = [], []
for i in range(n):
    for cmd, t in ((a, ta), (b, tb)):
        s = time.perf_counter(); subprocess.run(cmd, shell=True, check=True, stdout=subprocess.DEVNULL); t.append(time.perf_counter() - s)
print(f"A median {statistics.median(ta)*1000:.1f} ms  B median {statistics.median(tb)*1000:.1f} ms  ratio A/B {statistics.median(ta)/statistics.median(tb):.2f}")
