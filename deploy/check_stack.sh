#!/usr/bin/env bash
# Check the compose stack end to end: build the image once, start the services BEFORE their router
# (the reversed order), read poses on the host through the router's published port, stop and start
# the router and time the poses' return, then tear everything down.
#   deploy/check_stack.sh          (or: make compose-check)
# Needs Docker with Compose v2 and the host's locnerf environment (`make install`) for the pose probe.
# Environment (all optional):
#   COMPOSE_EXTRA  extra compose files, space-separated (e.g. a build override of the host)
#   BUILD_ARGS     extra arguments of `docker compose build` (e.g. --build-arg TORCH_INDEX=URL)
#   AFTER_BUILD    a command run after the build (e.g. making a local router image)
#   POSES          poses read before the router's restart (150); HEAD_START  seconds the services
#                  run without a router (15); PYTHON  the host's Python with locnerf (.venv/bin/python)
# Prints a line per step and ends with one line: check_stack {json of the figures}.
set -euo pipefail
cd "$(dirname "$0")/.."
POSES=${POSES:-150}
HEAD_START=${HEAD_START:-15}
PYTHON=${PYTHON:-.venv/bin/python}
SERVICES=(worker filter ingest)
files=(-f docker-compose.yml)
for extra in ${COMPOSE_EXTRA:-}; do files+=(-f "$extra"); done
compose() { docker compose "${files[@]}" "$@"; }
say() { echo "check_stack: $*" >&2; }
now() { date +%s.%N; }
since() { python3 -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 1))" "$1" "$(now)"; }

version=$(docker compose version --short 2>/dev/null || true)
case "$version" in
  2.* | v2.*) ;;
  *) say "needs Docker Compose v2 (\`docker compose\`), found '${version:-none}': the docker-compose v1 of some distributions rejects the file"; exit 2 ;;
esac
image=$(compose config --format json | python3 -c "import json, sys; print(json.load(sys.stdin)['services']['worker']['image'])")

trap 'say "tearing down"; compose down -v --remove-orphans >&2 2>&1 || true' EXIT

t=$(now)
# shellcheck disable=SC2086
compose build $BUILD_ARGS >&2
build_s=$(since "$t")
size_mb=$(docker image inspect "$image" --format '{{.Size}}' | python3 -c "import sys; print(round(int(sys.stdin.read()) / 1e6))")
say "built $image in ${build_s} s: ${size_mb} MB"
docker run --rm "$image" python -c "import cv2, torch, zenoh; print('imports: cv2', cv2.__version__, 'torch', torch.__version__)" >&2
if [ -n "${AFTER_BUILD:-}" ]; then bash -c "$AFTER_BUILD" >&2; fi

say "reversed start: ${SERVICES[*]} first, the router ${HEAD_START} s later"
compose up -d --no-deps "${SERVICES[@]}" >&2
sleep "$HEAD_START"
compose ps --all >&2
compose up -d zenohd >&2
figures=$("$PYTHON" deploy/pose_probe.py --count "$POSES" --stop "docker compose ${files[*]} stop zenohd" --start "docker compose ${files[*]} start zenohd")
retries=$(compose logs "${SERVICES[@]}" 2>&1 | grep -c "not reachable" || true)
progress=$(compose logs ingest 2>&1 | grep -c "events sent" || true)
restarts=$(docker inspect --format '{{.RestartCount}}' $(compose ps -aq "${SERVICES[@]}") | python3 -c "import sys; print(sum(map(int, sys.stdin.read().split())))")
compose logs --tail 3 "${SERVICES[@]}" >&2
echo "check_stack $(python3 -c "import json, sys; print(json.dumps({'image': sys.argv[1], 'build_s': float(sys.argv[2]), 'image_mb': int(sys.argv[3]), 'retry_warnings': int(sys.argv[5]), 'ingest_progress_lines': int(sys.argv[6]), 'container_restarts': int(sys.argv[7])} | json.loads(sys.argv[4])))" "$image" "$build_s" "$size_mb" "$figures" "$retries" "$progress" "$restarts")"
