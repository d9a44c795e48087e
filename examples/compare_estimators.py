"""Compare every estimator on one simulated scenario, then on your own data.

Runs the paper's direct solution, the library default (maximum likelihood), the paper's
iterative solver (Appendix C), a rotation-only (Kabsch) baseline, the GTSAM graph and the EKF
on Monte Carlo realisations of a scenario, prints the table (errors against the truth, error
divided by the Cramer-Rao bound, time per solve) and shows how to run the same on recorded,
sample-aligned rates.

    python examples/compare_estimators.py [--scenario weak_axis] [--runs 20] [--workers 2]
"""

import argparse

from fusion_gyrocal.evaluate.compare import compare
from fusion_gyrocal.evaluate.scenarios import list_scenarios, make_scenario


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="nominal", choices=list_scenarios())
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    args = ap.parse_args(argv)

    # 1. Monte Carlo over a named scenario: errors, error / bound, time per solve
    mc = compare(args.scenario, runs=args.runs, workers=args.workers, progress=False)
    mc.print()

    # 2. Your own recording: any two sample-aligned (N, 3) arrays in rad/s (no truth: estimates only).
    #    Here a simulated pair stands in for it.
    sc = make_scenario(args.scenario, rng=123)
    rec = compare((sc.omega_1, sc.omega_2), estimators=["direct", "default", "appendix_c", "rotation_only"],
                  progress=False)
    rec.print()
    print(rec.to_markdown())
    return mc, rec


if __name__ == "__main__":
    main()
