"""A long simulation neither dies nor outgrows the memory gate's estimate (issue 26, item 10):
`simulate --duration 1000` peaked at 6.9 GB in the limit-cycle check (Theil-Sen on every pair of
~30,000 cycles) and died. The run and its check now stay within BYTES_PER_SAMPLE a sample, the
figure the gate (haa_sym.io.budget) refuses by."""
import json
import os
import subprocess
import sys
import textwrap

from haa_sym.io.budget import BYTES_PER_SAMPLE

CHILD = textwrap.dedent("""
    import json, resource, sys
    from haa_sym import ClosedLoop, load_params
    from haa_sym.analysis.simulate import simulate
    from haa_sym.model.limits import Limits
    loop = ClosedLoop(load_params().with_values(beta=3.0))
    simulate(loop, 20000.0, 10.0, limits=Limits(V_max=24.0), duration=0.1)     # imports, compiled library
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    s = simulate(loop, 20000.0, 10.0, limits=Limits(V_max=24.0), duration=float(sys.argv[1]))
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"before": before, "after": after, "n": len(s.time), "verdict": s.verdict,
                      "cycles": s.oscillation.n_cycles}))
""")


def test_a_long_run_stays_within_the_gates_estimate():
    # 300 s at 1 kHz: the 24 V cycle of beta 3, P 20000, D 10 (59 Hz) has ~8,900 cycles in the
    # last half, 4 10^7 pairwise slopes before (0.3-0.6 GB); the bound: what the gate counts
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    p = subprocess.run([sys.executable, "-c", CHILD, "300"], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["verdict"] == "limit cycle" and r["cycles"] > 8000
    assert r["after"] - r["before"] <= r["n"] * BYTES_PER_SAMPLE
