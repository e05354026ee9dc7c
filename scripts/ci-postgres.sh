# A Postgres test database for the job-store tests, on a Debian machine where we are root.
# Sourced by .ci/run (so the export reaches `make test`); safe to source twice.
#
#   source scripts/ci-postgres.sh   → TREESIM_TEST_DATABASE_URL=postgresql://treesim:…/treesim_test
#
# Installs Debian's postgresql if needed, starts (or creates) a cluster, creates the role
# `treesim` and the database `treesim_test`, exports the URL, and stops the cluster on exit.
# In CI (CI=true) a failure fails: the source returns 1, which stops .ci/run (set -e), and
# the Postgres fixture fails rather than skips. Elsewhere a failure only warns: the
# Postgres tests then skip with their reason.

_treesim_pg() {
  local SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo -n"
  if ! command -v pg_lsclusters >/dev/null 2>&1; then
    echo "ci-postgres: installing postgresql"
    $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq postgresql >/dev/null \
      || return 1
  fi
  local line ver name port status
  line=$(pg_lsclusters --no-header 2>/dev/null | head -n 1)
  if [ -z "$line" ]; then
    ver=$(ls /usr/lib/postgresql | sort -V | tail -n 1)
    [ -n "$ver" ] || return 1
    $SUDO pg_createcluster "$ver" main >/dev/null || return 1
    line=$(pg_lsclusters --no-header | head -n 1)
  fi
  read -r ver name port status _ <<<"$line"
  if [ "$status" != "online" ]; then
    $SUDO pg_ctlcluster "$ver" "$name" start || return 1
    TREESIM_PG_STARTED="$ver $name"
  fi
  local psql=($SUDO runuser -u postgres -- psql -p "$port" -v ON_ERROR_STOP=1 -qtAX)
  if [ "$("${psql[@]}" -c "select 1 from pg_roles where rolname = 'treesim'")" != "1" ]; then
    "${psql[@]}" -c "create role treesim login password 'treesim'" || return 1
  fi
  if [ "$("${psql[@]}" -c "select 1 from pg_database where datname = 'treesim_test'")" != "1" ]; then
    "${psql[@]}" -c "create database treesim_test owner treesim" || return 1
  fi
  export TREESIM_TEST_DATABASE_URL="postgresql://treesim:treesim@127.0.0.1:${port}/treesim_test"
  psql "$TREESIM_TEST_DATABASE_URL" -qtAX -c "select 1" >/dev/null || return 1
}

_treesim_pg_stop() {
  if [ -n "${TREESIM_PG_STARTED:-}" ]; then
    # shellcheck disable=SC2086
    pg_ctlcluster $TREESIM_PG_STARTED stop >/dev/null 2>&1 || true
  fi
}

if _treesim_pg; then
  echo "ci-postgres: job-store tests will use $TREESIM_TEST_DATABASE_URL"
  trap _treesim_pg_stop EXIT
else
  unset TREESIM_TEST_DATABASE_URL
  _treesim_pg_stop
  if [ "${CI:-}" = "true" ]; then
    # a CI run that silently skipped the Postgres tests would pass without testing them
    echo "ci-postgres: error: no Postgres test database, and CI=true: the job-store tests need one" >&2
    # shellcheck disable=SC2317  # exit: when run rather than sourced
    return 1 2>/dev/null || exit 1
  fi
  echo "ci-postgres: warning: no Postgres test database; the Postgres job-store tests will skip" >&2
fi
