#!/usr/bin/env bash
# Whether a change left every output byte for byte as it was: runs the same small session through
# two `noisecal` binaries (simulate → calibrate → synth → renoise → interp → eval → report, and
# demo) and compares every file they wrote with `cmp`. For a refactoring that must not change
# what the tool writes: build the binary before the change, keep a copy, then
#
#   bash tests/bytes_unchanged.sh /path/to/noisecal-before target/release/noisecal
#
# Exit status 0 when every file is identical; the differing files are listed otherwise.
set -euo pipefail
before=${1:?usage: bytes_unchanged.sh BEFORE_BINARY AFTER_BINARY}
after=${2:?usage: bytes_unchanged.sh BEFORE_BINARY AFTER_BINARY}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# Each run writes into the same folder under relative paths (reports and eval text name their
# inputs), which is then moved aside.
run_all() {
  local bin=$1 out=.
  local q=--quiet
  "$bin" $q simulate --width 96 --height 64 --frames 6 --isos 100,400,1600 --structured --dark 3 \
    --seed 11 --dngs "$out/caps" --rec "$out/session.rec"
  "$bin" $q simulate --width 96 --height 64 --frames 4 --isos 100,400,1600 --index-offset 1000000 --seed 11 \
    --dngs "$out/held"
  "$bin" $q calibrate "$out/caps" -o "$out/dng.pack"
  "$bin" $q calibrate "$out/session.rec" -o "$out/rec.pack"
  "$bin" $q calibrate "$out/caps" --bin-width 8 --plain -o "$out/plain.pack"
  local held=(held/*.dng)
  local clean=${held[0]}
  "$bin" $q synth --pack "$out/dng.pack" --iso 400 --seed 5 "$clean" -o "$out/synth400.dng"
  "$bin" $q synth --pack "$out/dng.pack" --iso 800 --seed 5 --clean-at target "$clean" -o "$out/synth800.dng"
  "$bin" $q synth --pack "$out/dng.pack" --iso 400 --model hg "$clean" -o "$out/synth_hg.dng"
  "$bin" $q synth --pack "$out/rec.pack" --iso 1600 --components pixel,row "$clean" -o "$out/synth_rec.dng"
  "$bin" $q synth --pack "$out/dng.pack" --iso 400 --seed 9 "$out/held" -o "$out/synth_folder"
  "$bin" $q renoise --pack "$out/dng.pack" --to-iso 1600 --from-iso 400 --seed 3 "$out/synth400.dng" \
    -o "$out/renoise.dng"
  "$bin" $q renoise --pack "$out/dng.pack" --to-iso 1600 --from-iso 400 --method quantile \
    "$out/synth400.dng" -o "$out/renoise_q.dng"
  "$bin" $q interp --pack "$out/dng.pack" --iso 200 --iso 800 -o "$out/interp.pack"
  "$bin" $q eval --pack "$out/dng.pack" "$out/held" --seeds 2 --json "$out/eval.json" >"$out/eval.txt"
  "$bin" $q report --pack "$out/dng.pack" --eval "$out/eval.json" -o "$out/report.html"
  "$bin" $q inspect "$out/interp.pack" >"$out/inspect.txt"
  "$bin" $q demo --out "$out/demo" --width 96 --height 64 --frames 4 >"$out/demo.txt"
}

before=$(realpath "$before")
after=$(realpath "$after")
for side in before after; do
  mkdir "$work/run"
  (cd "$work/run" && run_all "${!side}" >/dev/null)
  mv "$work/run" "$work/$side"
done

status=0
count=0
while IFS= read -r -d '' f; do
  rel=${f#"$work/before/"}
  count=$((count + 1))
  if [[ ! -f "$work/after/$rel" ]]; then
    echo "missing after: $rel"; status=1
  elif ! cmp -s "$f" "$work/after/$rel"; then
    echo "differs: $rel"; status=1
  fi
done < <(find "$work/before" -type f -print0 | sort -z)
extra=$(cd "$work/after" && find . -type f | wc -l)
if [[ $extra -ne $count ]]; then
  echo "the after run wrote $extra files, the before run $count"; status=1
fi
if [[ $status -eq 0 ]]; then
  echo "bytes unchanged: $count files identical (packs, DNGs, recordings, eval JSON and text, report, demo)"
fi
exit $status
