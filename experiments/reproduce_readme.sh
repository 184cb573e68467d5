#!/usr/bin/env bash
# Regenerate every table and figure of README.md and the docs/ pages.
#
#   experiments/reproduce_readme.sh [OUT] [STAGE ...]
#
# OUT (default results/readme) receives every command's output; the figures
# the pages show are then copied to docs/*.png and the results they quote to
# docs/data/*.json, which tests/test_readme.py holds the pages' tables against, and experiments/docs_fingerprint.py records what each stage
# was computed with (docs/data/fingerprints.json), so a change to the code
# that would move a committed figure fails the tests until the stage is rerun.
# STAGE is any of: paper compare maps waypoints animate tune robustness
# compare-tuning compare-sizes compare-robust compare-robust-price compare-robust-kernels
# compare-robust-second tuner-load tuner-scaling law-derivative example-log bench
# (default: all but compare-robust-kernels and compare-robust-second, which
# record the second machine of docs/robustness.md and are run by name; on 2
# CPU cores, tune took 5 minutes, robustness 2 and compare-robust 18).
# Every command is seeded (the seed is its default unless named here), so a
# rerun prints the same tables. The exceptions: bench timings, and the
# searches' rows of compare-robust and compare-robust-second, whose budget is
# priced on the machine as it runs (compare-robust-price gives the price
# instead). CMA-ES's rows follow XLA's arithmetic alone, as the gradient's do:
# compare-robust-kernels shows them the same under another OpenBLAS kernel and
# with XLA limited to AVX2 (docs/robustness.md, "On a second machine").
# Runs with CMA-ES in evosax's LAPACK eigenbasis, which no stage makes now,
# stay for the page's account of it: docs/data/robust_compare_price_first_machine.json
# (compare-robust-price on that page's first machine) and
# docs/data/robust_compare_price_lapack_haswell.json,
# docs/data/robust_compare_price_lapack_skylakex.json and
# docs/data/robust_compare_price_lapack_sse4_2.json (compare-robust-kernels on the second).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-results/readme}
shift || true
STAGES=${*:-paper compare maps waypoints animate tune robustness compare-tuning compare-sizes compare-robust compare-robust-price tuner-load tuner-scaling law-derivative example-log bench}
mkdir -p "$OUT" docs/data

# The rows of a tune --compare record (its settings name this machine's code).
rows() {
  python -c 'import json, sys; rows = json.load(open(sys.argv[1]))["rows"]
open(sys.argv[2], "w").write(json.dumps(rows, indent=2) + "\n")' "$1" "$2"
}

for stage in $STAGES; do
  echo "== $stage" >&2
  case $stage in
    paper)  # Figs. 6-10, wheel speeds, the paper table (deterministic: no random poses)
      wmr-jax demo --out "$OUT/paper"
      for fig in fig6 fig7 fig8 fig9 fig10 wheels_k120; do cp "$OUT/paper/$fig.png" docs/; done
      cp "$OUT/paper/paper_table.json" docs/data/paper_table.json ;;
    compare)  # the controller table: 200,000 random poses, sample_poses seed 0
      wmr-jax compare --out "$OUT/compare" --poses 200000 --seed 0 --no-progress
      cp "$OUT/compare/comparison.json" docs/data/comparison.json ;;
    maps)  # the grid maps: 565 x 565 positions x 4 headings, 995,200 inside 5-80 cm
      wmr-jax sweep --out "$OUT/maps" --poses 1000000 --no-progress \
        --controller shim-sung aicardi astolfi-corke
      cp "$OUT/maps/maps_shim-sung.png" "$OUT/maps/winner.png" docs/
      cp "$OUT/maps/summary.json" docs/data/maps_summary.json ;;
    waypoints)
      wmr-jax waypoints --out "$OUT/waypoints"
      cp "$OUT/waypoints/soccer.png" docs/
      cp "$OUT/waypoints/soccer.json" docs/data/soccer.json ;;
    animate)  # real-time GIF of the paper's seven references
      wmr-jax animate --out "$OUT/robots.gif" --paper --seconds 2.5
      cp "$OUT/robots.gif" docs/robots.gif ;;
    tune)  # fixed gains, the gain schedule, the robust schedule and EKF (seed 0)
      wmr-jax tune --out "$OUT/tune"
      wmr-jax tune --out "$OUT/tune-schedule" --schedule
      wmr-jax tune --out "$OUT/tune-robust" --robust
      cp "$OUT/tune/tuning_curve.png" docs/ ;;
    robustness)  # after tune: the standard conditions judge its robust gain file
      wmr-jax robustness --out "$OUT/robustness" --runs 512
      cp "$OUT/robustness/robustness.png" docs/
      wmr-jax robustness --out "$OUT/robustness-standard" --runs 256 --controller shim-sung \
        --robust-gains "$OUT/tune-robust/tuned_gains.json" --noise-curve
      cp "$OUT/robustness-standard/standard_conditions.png" docs/
      cp "$OUT/robustness-standard/noise_curve.png" docs/
      cp "$OUT/robustness-standard/standard_conditions.json" docs/data/standard_conditions.json ;;
    compare-tuning)  # gradient vs CMA-ES vs random search, 3 seeds (2-7 minutes)
      wmr-jax tune --out "$OUT/tune-compare" --compare
      rows "$OUT/tune-compare/compare.json" docs/data/tune_compare.json ;;
    compare-sizes)  # the same on schedules of 30 and 60 knots (13 minutes on a fast 2-core machine)
      wmr-jax tune --out "$OUT/tune-compare-k30" --compare --schedule --knots 30
      rows "$OUT/tune-compare-k30/compare.json" docs/data/tune_compare_k30.json
      wmr-jax tune --out "$OUT/tune-compare-k60" --compare --schedule --knots 60
      rows "$OUT/tune-compare-k60/compare.json" docs/data/tune_compare_k60.json ;;
    compare-robust)  # the joint robust problem: gradient vs CMA-ES vs random search, 3 seeds
      wmr-jax tune --out "$OUT/tune-robust-compare" --robust --compare ;;
    compare-robust-price)  # the same at a given price: as many candidates on any machine (OpenBLAS's Haswell kernels)
      OPENBLAS_CORETYPE=Haswell wmr-jax tune --out "$OUT/tune-robust-compare-price" --robust --compare --price 5
      cp "$OUT/tune-robust-compare-price/robust_compare.json" docs/data/robust_compare_price.json
      # 20 % either side: docs/data/robust_compare_price_4.json and docs/data/robust_compare_price_6.json
      for price in 4 6; do
        wmr-jax tune --out "$OUT/tune-robust-compare-price-$price" --robust --compare --price $price
        cp "$OUT/tune-robust-compare-price-$price/robust_compare.json" "docs/data/robust_compare_price_$price.json"
      done ;;
    compare-robust-kernels)  # the same under OpenBLAS's SkylakeX kernels, and XLA at AVX2 and SSE4.2 (needs AVX-512)
      OPENBLAS_CORETYPE=SkylakeX wmr-jax tune --out "$OUT/price-skylakex" --robust --compare --price 5
      cp "$OUT/price-skylakex/robust_compare.json" docs/data/robust_compare_price_skylakex.json
      OPENBLAS_CORETYPE=Haswell XLA_FLAGS=--xla_cpu_max_isa=AVX2 \
        wmr-jax tune --out "$OUT/price-avx2" --robust --compare --price 5
      cp "$OUT/price-avx2/robust_compare.json" docs/data/robust_compare_price_avx2.json
      OPENBLAS_CORETYPE=Haswell XLA_FLAGS=--xla_cpu_max_isa=SSE4_2 \
        wmr-jax tune --out "$OUT/price-sse4_2" --robust --compare --price 5
      cp "$OUT/price-sse4_2/robust_compare.json" docs/data/robust_compare_price_sse4_2.json ;;
    compare-robust-second)  # the default command alone, then sharing its core with a CPU hog
      OPENBLAS_CORETYPE=Haswell taskset -c 1 wmr-jax tune --out "$OUT/second-alone" --robust --compare
      cp "$OUT/second-alone/robust_compare.json" docs/data/robust_compare_second_alone.json
      taskset -c 0 python -c "while True: pass" & hog=$!
      trap 'kill $hog 2>/dev/null' EXIT
      OPENBLAS_CORETYPE=Haswell taskset -c 0 wmr-jax tune --out "$OUT/second-load" --robust --compare
      kill $hog
      cp "$OUT/second-load/robust_compare.json" docs/data/robust_compare_second_load.json ;;
    tuner-load)  # the reduced robust comparison as the machine is, then beside two CPU hogs
      rm -f docs/data/tuner_load_quiet.json docs/data/tuner_load_hog.json
      python experiments/tuner_scaling.py --sizes 38 --iters 30 --poses 8 --nonideal-poses 2 \
        --eval-poses 64 --out docs/data/tuner_load_quiet.json
      python -c "while True: pass" & hog1=$!
      python -c "while True: pass" & hog2=$!
      trap 'kill $hog1 $hog2 2>/dev/null' EXIT
      python experiments/tuner_scaling.py --sizes 38 --iters 30 --poses 8 --nonideal-poses 2 \
        --eval-poses 64 --out docs/data/tuner_load_hog.json
      kill $hog1 $hog2 ;;
    tuner-scaling)  # tune --robust --compare at 38, 101 and 285 parameters; resumes where the file stops
      # (after a change to CMA-ES alone: python experiments/tuner_scaling.py --rerun-cma-es)
      python experiments/tuner_scaling.py --sizes 38 101 285 --out docs/data/tuner_scaling.json ;;
    law-derivative)  # the robust loss's gradient, the law's Jacobian against JAX's own derivative
      python experiments/law_derivative.py --json docs/data/law_derivative.json
      python experiments/law_derivative.py --poses 32 --estimators ekf \
        --json docs/data/law_derivative_32.json ;;
    example-log)  # a simulated robot's 1-minute log for trying wmr-jax identify (tests/test_identify.py holds it)
      python experiments/identified_vs_base.py --log-only --minutes 1 --out "$OUT/example-log"
      cp "$OUT/example-log/log.csv" docs/data/example_log.csv ;;
    bench)
      wmr-jax bench --json "$OUT/bench.json" --wait-idle 60 ;;
    *) echo "unknown stage $stage" >&2; exit 2 ;;
  esac
  # What the stage's docs files were computed with (tests/test_readme.py checks it).
  case $stage in
    paper|compare|maps|waypoints|animate|tune|robustness)
      python experiments/docs_fingerprint.py record "$stage" ;;
  esac
done
