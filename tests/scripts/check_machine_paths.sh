#!/usr/bin/env bash
# Fails when a tracked file names an absolute path of some machine: a folder under one of the
# top-level directories listed in `roots` (home and user folders, temporary and work folders,
# mounts, system folders), a Windows drive path, or a file:// URL. Paths in the repository are
# relative to it; commands in docs use placeholders (CAPTURE, ASSET) instead.
#
# Legitimate absolute paths are allowed one by one in `allowed` (a path matches when it starts
# with an entry); files kept verbatim from third parties are listed in `excluded`. URLs pass
# because their paths follow a host name, not a delimiter.
#
# Usage: bash tests/scripts/check_machine_paths.sh   (exit 0: none found; 1: found, listed)
set -euo pipefail
cd "$(dirname "$0")/../.."

roots='home|root|tmp|temp|work|workspace|Users|mnt|media|opt|srv|var|private|scratch|data|usr|etc|lib|lib64|bin|sbin|run|nix|Volumes|dev|proc|sys'
# An absolute path starts the text or follows a character that cannot be part of a relative
# path or a URL (so `target/tmp/x`, `../tmp` and `https://host/home/x` pass).
unix="(^|[^A-Za-z0-9_.~/-])/($roots)([/[:space:]\"'\`),;:]|\$)[^[:space:]\"'\`),;]*"
windows="(^|[^A-Za-z0-9_])[A-Z]:[\\\\/]{1,2}[A-Za-z][^[:space:]\"'\`),;]*"
file_url='file:///[^[:space:]"'"'"'`),;]*'

allowed=(
  /dev/null      # shell redirections
  /dev/stdin
  /dev/stdout
  /dev/stderr
  /usr/bin/env   # shebangs
  /proc/cpuinfo  # the machine and its load in benchmark headers (Linux)
  /proc/meminfo
  /proc/loadavg
)
excluded=(
  ':!crates/cli/assets/DejaVuSans.LICENSE' # the font's license, verbatim
  ':!tests/scripts/check_machine_paths.sh' # this script's patterns
)

if ! git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  echo "$0: not a git checkout: the check reads the tracked files from git" >&2
  exit 2
fi
# git grep exits 1 when nothing matches, above 1 on an error.
rc=0
hits=$(git grep -n -I -o -E -e "$unix" -e "$windows" -e "$file_url" -- . "${excluded[@]}") || rc=$?
if [ "$rc" -gt 1 ]; then
  echo "$0: git grep failed (exit $rc)" >&2
  exit 2
fi

found=0
while IFS= read -r hit; do
  [ -n "$hit" ] || continue
  # hit is FILE:LINE:MATCH; the match may start with the delimiter before the path.
  file_line=${hit%%:*}
  rest=${hit#*:}
  line=${rest%%:*}
  match=${rest#*:}
  path=${match#"${match%%[/A-Za-z]*}"}
  ok=0
  for a in "${allowed[@]}"; do
    case "$path" in "$a"*) ok=1 ;; esac
  done
  if [ "$ok" = 0 ]; then
    echo "$file_line:$line: absolute machine path: $path"
    found=1
  fi
done <<<"$hits"

if [ "$found" = 1 ]; then
  echo "tracked files name absolute paths of a machine (make them relative, or use a placeholder;"
  echo "a path every machine has may be added to 'allowed' in $0)"
  exit 1
fi
echo "no absolute machine paths in tracked files"
