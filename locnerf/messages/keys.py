"""The key-expression table: every Zenoh key, its message type and its producer.

All keys live under ``locnerf/<robot_id>/``. ``docs/SERVICES.md`` prints this table.
"""

from __future__ import annotations

from dataclasses import dataclass

from locnerf.messages import schemas


@dataclass(frozen=True)
class Topic:
    """One row of the table: ``suffix`` below ``locnerf/<robot_id>/``."""

    suffix: str
    message: str
    producer: str
    description: str


IMAGE = Topic(
    "sensors/image",
    schemas.ImageHeader.__name__ + " + raw pixels (+ raw depth pixels)",
    "sensor_ingest",
    "newest camera frame (RGB-D cameras: with its depth image)",
)
ODOMETRY = Topic("sensors/odom", schemas.Odometry.__name__, "sensor_ingest", "VIO body pose, 15 Hz")
GROUND_TRUTH = Topic("sensors/ground_truth", schemas.PoseStamped.__name__, "sensor_ingest", "true camera pose when the source knows it")
POSE = Topic("filter/pose", schemas.PoseEstimate.__name__, "filter_loop", "pose estimate at the odometry rate")
PARTICLES = Topic("filter/particles", schemas.ParticleCloud.__name__, "filter_loop", "particle cloud, lower rate")
STATUS = Topic("filter/status", schemas.FilterStatus.__name__, "filter_loop", "rates, latency, counters, 1 Hz")
WORKER_STATUS = Topic("worker/status/{worker_id}", schemas.ServiceStatus.__name__, "nerf_worker", "requests answered, bad messages by kind, 1 Hz")
INGEST_STATUS = Topic("ingest/status/{ingest_id}", schemas.ServiceStatus.__name__, "sensor_ingest", "events sent, bad messages by kind, 1 Hz")
UPDATE_REQUEST = Topic("update/request/{worker_id}", schemas.UpdateRequest.__name__, "filter_loop", "one shard for one worker")
UPDATE_RESULT = Topic("update/result", schemas.UpdateResult.__name__, "nerf_worker", "log-likelihoods of a shard")
UPDATE_REFUSAL = Topic("update/refusal", schemas.UpdateRefusal.__name__, "nerf_worker", "a shard the worker did not compute: wrong map, bad request or failure")
WORKER_ALIVE = Topic("alive/worker/{worker_id}/{device}/{map_checksum}", "liveliness token", "nerf_worker", "a live worker, its device and its map's checksum")
VIEW_ALIVE = Topic("alive/view", "liveliness token", "locnerf view", "a view subscribed to the robot's topics and recording them")
INITIAL_POSE = Topic("command/initial_pose", schemas.InitialPoseCommand.__name__, "operator (locnerf send)", "re-initialise around a pose")
GLOBAL_LOCALIZATION = Topic("command/global_localization", schemas.GlobalLocalizationCommand.__name__, "operator (locnerf send)", "re-initialise over the map")

TABLE: tuple[Topic, ...] = (
    IMAGE,
    ODOMETRY,
    GROUND_TRUTH,
    POSE,
    PARTICLES,
    STATUS,
    WORKER_STATUS,
    INGEST_STATUS,
    UPDATE_REQUEST,
    UPDATE_RESULT,
    UPDATE_REFUSAL,
    WORKER_ALIVE,
    VIEW_ALIVE,
    INITIAL_POSE,
    GLOBAL_LOCALIZATION,
)


def key(robot_id: str, topic: Topic, **fields: str) -> str:
    """The full key expression of ``topic`` for ``robot_id``, placeholders filled from ``fields``."""
    if not robot_id or any(c in robot_id for c in "/*$?#"):
        raise ValueError(f"robot id {robot_id!r}: expected a non-empty name without / * $ ? #")
    return f"locnerf/{robot_id}/" + topic.suffix.format(**fields)


def workers_alive_pattern(robot_id: str) -> str:
    """Key expression matching every worker liveliness token of ``robot_id``."""
    return key(robot_id, WORKER_ALIVE, worker_id="*", device="*", map_checksum="*")


@dataclass(frozen=True)
class WorkerToken:
    """What a worker's liveliness token announces."""

    worker_id: str
    device: str
    map_checksum: str


def parse_worker_token(token_key: str) -> WorkerToken:
    """``locnerf/<robot>/alive/worker/<id>/<device>/<map_checksum>`` -> its worker id, device and map checksum."""
    parts = token_key.split("/")
    if len(parts) != 7 or parts[2:4] != ["alive", "worker"]:
        raise ValueError(f"{token_key!r}: expected locnerf/<robot>/alive/worker/<worker_id>/<device>/<map_checksum>")
    return WorkerToken(*parts[4:])


def markdown_table() -> str:
    """The table in Markdown, for the docs."""
    rows = ["| key (under `locnerf/<robot_id>/`) | message | producer | meaning |", "|---|---|---|---|"]
    rows += [f"| `{t.suffix}` | {t.message} | {t.producer} | {t.description} |" for t in TABLE]
    return "\n".join(rows)
