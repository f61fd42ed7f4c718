#!/usr/bin/env bash
# Start the local PostgreSQL and Redis the scale-out service tests use
# (tests/service/conftest.py: postgres@127.0.0.1:5432 without a password, redis at
# 127.0.0.1:6379). Idempotent; quiet when both are already up.
#
# On a fresh machine the server packages are installed with apt-get (postgresql,
# redis-server), and the local cluster is set to trust connections from 127.0.0.1.
# Anything that cannot be done ends the script with status 1 and the cause: a missing
# server is an install step or a clear error, never a page of fixture errors later.
set -euo pipefail

PG_HOST=127.0.0.1 PG_PORT=5432 REDIS_PORT=6379
PG_CONF=${PRT_SERVICES_PG_CONF:-/etc/postgresql}      # overridable for tests/test_services_script.py
WAIT_S=${PRT_SERVICES_WAIT_S:-20}                    # how long a started server may take
LOG_DIR=${PRT_SERVICES_LOG_DIR:-/tmp/prtcore-services}
mkdir -p "$LOG_DIR"

die() { echo "services: $*" >&2; exit 1; }

as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"
  elif command -v sudo >/dev/null; then sudo -n "$@"
  else die "need root to run: $* (run as root, or install it yourself)"; fi
}

install_packages() {  # install_packages PKG... ; fails loudly with apt-get's output
  command -v apt-get >/dev/null ||
    die "$* missing and apt-get is not available: install $* by hand"
  echo "services: installing $* with apt-get" >&2
  as_root env DEBIAN_FRONTEND=noninteractive apt-get update -q >"$LOG_DIR/apt.log" 2>&1 ||
    { tail -20 "$LOG_DIR/apt.log" >&2; die "apt-get update failed (log: $LOG_DIR/apt.log)"; }
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
    "$@" >>"$LOG_DIR/apt.log" 2>&1 ||
    { tail -20 "$LOG_DIR/apt.log" >&2; die "apt-get install $* failed (log: $LOG_DIR/apt.log)"; }
}

# -- what must be installed --------------------------------------------------------------
missing=()
{ command -v pg_isready >/dev/null && command -v pg_ctlcluster >/dev/null; } ||
  missing+=(postgresql postgresql-client)
command -v psql >/dev/null || missing+=(postgresql-client)
{ command -v redis-server >/dev/null && command -v redis-cli >/dev/null; } ||
  missing+=(redis-server redis-tools)
[ ${#missing[@]} = 0 ] || install_packages "${missing[@]}"
for tool in pg_isready pg_ctlcluster psql redis-server redis-cli; do
  command -v "$tool" >/dev/null || die "$tool still missing after installing ${missing[*]}"
done

pg_up() { pg_isready -q -h "$PG_HOST" -p "$PG_PORT"; }
redis_up() { [ "$(redis-cli -h 127.0.0.1 -p "$REDIS_PORT" ping 2>/dev/null)" = PONG ]; }

wait_for() {  # wait_for NAME CHECK LOG
  local deadline=$((SECONDS + WAIT_S))
  while [ "$SECONDS" -le "$deadline" ]; do "$2" && return 0; sleep 0.2; done
  if [ -f "$3" ]; then tail -20 "$3" >&2; fi
  die "$1 did not come up within $WAIT_S s (log: $3)"
}

# -- PostgreSQL --------------------------------------------------------------------------
if ! pg_up; then
  version=$(ls "$PG_CONF" 2>/dev/null | sort -V | tail -1)
  [ -n "$version" ] || die "PostgreSQL is installed but has no cluster in $PG_CONF"
  hba=$PG_CONF/$version/main/pg_hba.conf
  [ -f "$hba" ] || die "no $hba: the $version/main cluster is incomplete"
  # The tests connect as postgres@127.0.0.1 without a password.
  if ! grep -Eq '^host[[:space:]]+all[[:space:]]+all[[:space:]]+127\.0\.0\.1/32[[:space:]]+trust' "$hba"; then
    echo "services: letting $hba trust connections from 127.0.0.1 (test machine)" >&2
    as_root sed -i '1i host all all 127.0.0.1/32 trust' "$hba"
  fi
  pglog=/var/log/postgresql/postgresql-$version-main.log
  echo "services: starting PostgreSQL $version" >&2
  as_root pg_ctlcluster --skip-systemctl-redirect "$version" main start >"$LOG_DIR/pg.log" 2>&1 ||
    { cat "$LOG_DIR/pg.log" >&2; if [ -f "$pglog" ]; then tail -20 "$pglog" >&2; fi
      die "pg_ctlcluster $version main start failed"; }
  wait_for PostgreSQL pg_up "$pglog"
fi

# -- Redis -------------------------------------------------------------------------------
if ! redis_up; then
  echo "services: starting Redis" >&2
  mkdir -p /tmp/prtcore-redis
  redis-server --daemonize yes --bind 127.0.0.1 --port "$REDIS_PORT" --save "" \
    --appendonly no --dir /tmp/prtcore-redis --logfile "$LOG_DIR/redis.log" ||
    { if [ -f "$LOG_DIR/redis.log" ]; then tail -20 "$LOG_DIR/redis.log" >&2; fi
      die "redis-server failed to start"; }
  wait_for Redis redis_up "$LOG_DIR/redis.log"
fi

# -- what the tests need from them -------------------------------------------------------
psql -h "$PG_HOST" -p "$PG_PORT" -U postgres -d postgres -Atqc 'select 1' >/dev/null 2>"$LOG_DIR/psql.log" ||
  { cat "$LOG_DIR/psql.log" >&2
    die "PostgreSQL is up but postgres@$PG_HOST:$PG_PORT cannot connect without a password"; }
