#!/bin/bash
# Re-runs the experiments of docs/results.md at one committed revision, in a worktree of it
# (so the runs record that revision, clean, whatever the checkout holds meanwhile).
#
# Usage: tools/rerun_results.sh REV WORKERS [table1 gvn_v2 gvn_v3 explore_bench ariadne
#        ablation ablation_v2 ablation_v3 lobby_real realistic realistic_truth
#        realistic_odometry realistic_imu teams]
# Runs go to runs/rerun_REV/<experiment>; started again, bench skips the finished episodes.
# Then: mjexplore collect runs/rerun_REV/<experiment> --experiment <experiment> and
# mjexplore report. Needs ../shared/data (the Explore-Bench and ARiADNE maps), or the folder
# MJEXPLORE_SHARED names.
#
# In a copy without git history (a machine the checkout was copied to), it runs in place:
# MJEXPLORE_GIT_REVISION must name the commit the copy holds (every run records it) and be
# given as REV; MJEXPLORE_PYTHON is the interpreter (default python3 there, .venv's here).
set -eu
[ $# -ge 2 ] || { echo "usage: $0 REV WORKERS [EXPERIMENT...]" >&2; exit 2; }
if ROOT=$(git rev-parse --show-toplevel 2> /dev/null); then
  REV=$(git rev-parse --short "$1")
  WT=$ROOT/runs/wt_$REV
  [ -d "$WT" ] || git -C "$ROOT" worktree add --detach "$WT" "$REV"
  PY=${MJEXPLORE_PYTHON:-$ROOT/.venv/bin/python}
else
  [ "${MJEXPLORE_GIT_REVISION:-}" = "$1" ] || {
    echo "no git history here: set MJEXPLORE_GIT_REVISION=$1 (the commit this copy holds)" >&2
    exit 2; }
  REV=${1:0:7}; ROOT=$PWD; WT=$ROOT; PY=${MJEXPLORE_PYTHON:-python3}
fi
W=$2; shift 2
EXPERIMENTS=${*:-table1 gvn_v2 gvn_v3 explore_bench ariadne ablation ablation_v2 ablation_v3 lobby_real realistic realistic_truth realistic_odometry realistic_imu}
SHARED=$(cd "${MJEXPLORE_SHARED:-$ROOT/../shared}" && pwd)
OUT=$ROOT/runs/rerun_$REV
mkdir -p "$OUT"
if [ "$WT" != "$ROOT" ]; then
  ln -sfn "$SHARED" "$ROOT/runs/shared"  # ../shared as seen from the worktree.
  EB=$(ls "$SHARED"/data/explore_bench/*.yaml | sed "s#$SHARED#../shared#" | paste -sd,)
else
  EB=$(ls "$SHARED"/data/explore_bench/*.yaml | paste -sd,)
fi
mj() { (cd "$WT" && PYTHONPATH="$WT${PYTHONPATH:+:$PYTHONPATH}" "$PY" -c \
    'import sys; from mjexplore.cli import main; sys.exit(main(sys.argv[1:]))' "$@"); }
ALL=nearest,pocket_nearest,explore_lite,frontier_tsp,rrt,potential,cnn:cnn_paper,gvn:gvn_paper,oracle
for e in $EXPERIMENTS; do
  echo "== $e $(date -u +%FT%TZ)"
  case $e in
    table1) mj bench --scenes loop_with_corridor,maze,office --explorers $ALL,gvn_v3 --seeds 10 \
              --workers "$W" --out "$OUT/table1" ;;
    gvn_v2) mj bench --scenes loop_with_corridor,maze,office \
              --explorers nearest,potential,cnn_v2,gvn_v2 \
              --seeds 10 --workers "$W" --out "$OUT/gvn_v2" ;;
    gvn_v3) mj bench --scenes loop_with_corridor,maze,office \
              --explorers nearest,potential,gvn_v2,gvn_v3 \
              --seeds 10 --workers "$W" --out "$OUT/gvn_v3" ;;
    explore_bench) mj bench --scenes "$EB" --explorers $ALL,cnn_v2,gvn_v2,gvn_v3 --seeds 2 --lidar-range 7 \
              --workers "$W" --out "$OUT/explore_bench" ;;
    realistic) mj bench --scenes loop_with_corridor,maze,office --explorers $ALL,gvn_v3 --seeds 5 \
              --lidar-model lds01 --odometry-error typical --localization scan_matching \
              --max-time 3600 --workers "$W" --out "$OUT/realistic" ;;
    realistic_truth|realistic_odometry|realistic_imu)
      case $e in
        realistic_truth) LOCALIZE="--localization ground_truth" ;;
        realistic_odometry) LOCALIZE="--localization odometry" ;;
        realistic_imu) LOCALIZE="--odometry-heading imu --localization scan_matching" ;;
      esac
      mj bench --scenes loop_with_corridor,maze,office --explorers nearest --seeds 5 \
        --lidar-model lds01 --odometry-error typical $LOCALIZE --max-time 3600 \
        --workers "$W" --out "$OUT/$e" ;;
    ablation) mj bench --scenes loop_with_corridor,maze \
              --explorers gvn_none,gvn_naive,gvn_unmasked,gvn:gvn_paper --seeds 5 --workers "$W" \
              --out "$OUT/ablation" ;;
    ablation_v2) mj bench --scenes loop_with_corridor,maze \
              --explorers gvn_v2_none,gvn_v2_naive,gvn_v2_unmasked,gvn_v2 --seeds 5 \
              --workers "$W" --out "$OUT/ablation_v2" ;;
    ablation_v3) mj bench --scenes loop_with_corridor,maze \
              --explorers gvn_v3_none,gvn_v3_naive,gvn_v3_unmasked,gvn_v3 --seeds 5 \
              --workers "$W" --out "$OUT/ablation_v3" ;;
    lobby_real) mj bench --scenes lobby --explorers gvn:gvn_paper,potential,nearest,pocket_nearest,gvn_v3 --profile real \
              --seeds 5 --workers 1 --out "$OUT/lobby_real" ;;
    teams)  # Collect: office3 with --experiment teams, then office2 with --merge.
      mj bench --scenes office --robots 3 --explorers assign_greedy,oracle --seeds 5 --workers 1 \
        --out "$OUT/teams/office3"
      mj bench --scenes office --robots 2 --explorers assign_greedy,nearest,oracle --seeds 5 \
        --workers 1 --out "$OUT/teams/office2"
      mj bench --scenes office --robots 2 --unknown-starts --explorers assign_greedy --seeds 5 \
        --workers 1 --out "$OUT/teams/office2"
      mj bench --scenes loop_with_corridor,maze --robots 2 --explorers assign_greedy,nearest \
        --seeds 3 --workers 1 --out "$OUT/teams/office2" ;;
    ariadne)
      for f in "$SHARED"/data/ariadne_test/img_*.png; do
        d=$OUT/ariadne_scenes/$(basename "$f" .png)
        [ -d "$d" ] || mj scene-gen --from-map "$f" --resolution 0.1 --out "$d" > /dev/null
      done
      mj bench --scenes "$(ls -d "$OUT"/ariadne_scenes/* | paste -sd,)" --explorers $ALL,cnn_v2,gvn_v2,gvn_v3 \
        --seeds 1 --lidar-range 8 --workers "$W" --out "$OUT/ariadne" ;;
    *) echo "unknown experiment $e" >&2; exit 2 ;;
  esac
done
echo "== done $(date -u +%FT%TZ)"
