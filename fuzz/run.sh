#!/usr/bin/env bash
# Fuzzes targets one after another (one core each, in turn) for SECONDS each, from the
# seed corpus (python3 fuzz/seed_corpus.py), and prints one table row per target:
# executions, coverage (edges, features), crash artifact if any.
#   fuzz/run.sh 600                 # every target, 10 minutes each
#   fuzz/run.sh 20 pcd ply          # a smoke run of two targets
# Logs: fuzz/logs/<target>.log; crashes: fuzz/artifacts/<target>/.
set -uo pipefail
cd "$(dirname "$0")"
seconds=${1:?usage: fuzz/run.sh SECONDS [TARGET...]}
shift
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo +nightly fuzz list)
fi
[ -d corpus ] || python3 seed_corpus.py
mkdir -p logs
status=0
echo "| target | seconds | executions | cov (edges) | ft (features) | crash |"
echo "|---|---|---|---|---|---|"
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t"
  cargo +nightly fuzz run "$t" "corpus/$t" -- \
    -max_total_time="$seconds" -print_final_stats=1 -timeout=10 -rss_limit_mb=2048 \
    >"logs/$t.log" 2>&1
  rc=$?
  execs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "logs/$t.log" | tail -1 | awk '{print $2}')
  last=$(grep -E '^#[0-9]+' "logs/$t.log" | tail -1)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
  crash=$(grep -o 'Test unit written to [^ ]*' "logs/$t.log" | tail -1 | awk '{print $5}')
  if [ "$rc" -ne 0 ]; then status=1; fi
  echo "| $t | $seconds | ${execs:-?} | ${cov:-?} | ${ft:-?} | ${crash:-none} |"
done
exit $status
