#!/usr/bin/env bash
# Every file the docs name exists: each `path.ext` in backticks and each relative Markdown link in
# the tracked Markdown files (README.md, docs/, android/) must be a tracked file. A name with a
# folder (`format/pack_v1.rs`, `rust/cli/tests/dense_sweep.rs`) must end a tracked path at a folder
# boundary; a bare name (`drift.rs`) must be a file next to the doc or the name of exactly one tracked file. Run by tests/run_all.sh, so a
# file renamed or moved without its docs fails CI with the stale name and where it is written.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

tracked=$(git ls-files)
status=0
while IFS= read -r doc; do
  dir=$(dirname "$doc")
  # `name.ext` in backticks, and ](relative/link) targets.
  names=$(grep -on '`[A-Za-z0-9_./-]*\.\(rs\|py\|pyi\|sh\|md\|toml\|kt\|kts\|json\|xml\|java\)`' "$doc" | tr -d '`' || true)
  links=$(grep -on '\](\([^)#: ]*\))' "$doc" | sed 's/\](\(.*\))/\1/' || true)
  while IFS=: read -r line name; do
    [[ -n "$name" ]] || continue
    found=0
    if [[ -e "$dir/$name" ]]; then
      found=1
    elif [[ "$name" == */* ]]; then
      trimmed=${name#./}
      # Relative to the doc, from the root, or the tail of a tracked path.
      if [[ -e "$dir/$trimmed" || -e "$trimmed" ]] || grep -qE "(^|/)${trimmed//./\\.}\$" <<<"$tracked"; then
        found=1
      fi
    else
      n=$(grep -cE "(^|/)${name//./\\.}\$" <<<"$tracked" || true)
      if [[ $n -gt 1 ]]; then
        echo "$doc:$line names $name, which $n files are called: give its folder too" >&2
        status=1
        continue
      fi
      [[ $n -eq 1 ]] && found=1
    fi
    if [[ $found -eq 0 ]]; then
      echo "$doc:$line names $name, which is not a file of the repository" >&2
      status=1
    fi
  done < <(printf '%s\n%s\n' "$names" "$links")
done < <(git ls-files '*.md')
if [[ $status -eq 0 ]]; then
  echo "doc paths: every file the docs name exists" >&2
fi
exit $status
