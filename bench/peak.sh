# Sourced by the bench scripts. peak RSS_FILE CMD...: runs CMD (its stdout and stderr go to the
# caller's) and writes CMD's peak resident memory in MB to RSS_FILE; returns CMD's status.
# GNU time where it is installed, else Python's getrusage of the child ($PYTHON or python3):
# GPU machines without GNU time still report memory.
peak() {
  local f=$1 rc
  shift
  rm -f "$f"
  if [ -x /usr/bin/time ]; then
    rc=0
    /usr/bin/time -f "%M" -o "$f" "$@" || rc=$?
    echo $(( $(tail -1 "$f") / 1024 )) > "$f"
    return $rc
  fi
  "${PYTHON:-python3}" -c 'import resource, subprocess, sys
r = subprocess.run(sys.argv[2:]).returncode
open(sys.argv[1], "w").write("%d\n" % (resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss // 1024))
sys.exit(r)' "$f" "$@"
}
