"""Every rerun call of ``locnerf view``: what is logged where, and the layout of the viewer.

Entities (metres, the map's metric world frame; cameras with OpenGL axes, rerun's ``RUB``):

| entity | archetype | what |
|---|---|---|
| ``world/map`` | Points3D (static) | occupied voxels of the map, coloured |
| ``world/particles`` | Points3D | the particle cloud, brighter for heavier particles |
| ``world/estimate`` | Transform3D | the filter's pose; ``world/estimate/camera``: Pinhole (frustum) and the camera image |
| ``world/truth`` | Transform3D | the true pose when the source knows it; ``world/truth/camera``: Pinhole |
| ``world/trajectory/estimate``, ``world/trajectory/truth`` | LineStrips3D | the paths so far |
| ``camera/image``, ``camera/render`` | Image | the camera image and the map rendered at the estimate |
| ``error/*``, ``filter/*``, ``rates/*`` | Scalars | error, spread, particles, effective sample size, latency, rates |

Everything is stamped on the ``stamp`` timeline with the messages' own sensor stamps (whole nanoseconds).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from locnerf.errors import LocnerfInputError
from locnerf.maps.cloud import MapCloud
from locnerf.messages.schemas import FilterStatus, ParticleCloud, PoseEstimate, PoseStamped
from locnerf.render.camera import PinholeIntrinsics

APPLICATION_ID = "locnerf_view"
TIMELINE = "stamp"
ESTIMATE = "world/estimate"
TRUTH = "world/truth"
PARTICLES = "world/particles"
MAP = "world/map"
ESTIMATE_COLOUR = (230, 60, 40)
TRUTH_COLOUR = (40, 200, 80)


def blueprint(eye: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> rrb.Blueprint:
    """The layout: the 3-D world on the left, looked at from ``eye`` = (position, target, up) when given; camera image
    and render, then the time series, on the right; the time cursor follows the newest data."""
    eye_controls = None if eye is None else rrb.EyeControls3D(position=eye[0], look_target=eye[1], eye_up=eye[2])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="map, particles, poses", origin="world", eye_controls=eye_controls),
            rrb.Vertical(
                rrb.Horizontal(
                    rrb.Spatial2DView(name="camera", origin="camera/image"),
                    rrb.Spatial2DView(name="map at the estimate", origin="camera/render"),
                ),
                rrb.TimeSeriesView(name="error and spread (m)", origin="/", contents=["error/translation_m", "filter/spread_m"]),
                rrb.TimeSeriesView(name="error (°)", origin="error/rotation_deg"),
                rrb.TimeSeriesView(name="rates (Hz)", origin="rates"),
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE, play_state="following", state="collapsed"),
        collapse_panels=True,
    )


def has_display() -> bool:
    """Whether a native window can open: always off Linux; on Linux when X11 or Wayland is there."""
    return sys.platform != "linux" or any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def spawn_viewer(recording: rr.RecordingStream) -> None:
    """Start the rerun viewer (shipped in the rerun-sdk wheel) for ``recording``.

    Raises:
        LocnerfInputError: no display (the viewer would die and the recording wait for it), or no viewer on PATH.
    """
    if not has_display():
        raise LocnerfInputError(
            "no display (DISPLAY and WAYLAND_DISPLAY unset) for the rerun viewer: record with --save run.rrd, then open it with `rerun run.rrd`"
        )
    try:
        recording.spawn(connect=False)
    except RuntimeError as error:
        raise LocnerfInputError(
            f"the rerun viewer did not start: {str(error).strip().splitlines()[0]} (the `rerun` command of the environment must be on PATH)"
        ) from None


def open_recording(save: Path | None, spawn: bool) -> rr.RecordingStream:
    """A recording that writes to ``save`` (a .rrd file), streams to a spawned viewer, or both.

    Raises:
        LocnerfInputError: ``spawn`` where no viewer can open (:func:`spawn_viewer`).
    """
    recording = rr.RecordingStream(APPLICATION_ID)
    layout = blueprint()
    if spawn:
        spawn_viewer(recording)
    sinks: list[rr.GrpcSink | rr.FileSink] = ([rr.GrpcSink()] if spawn else []) + ([rr.FileSink(save)] if save is not None else [])
    recording.set_sinks(*sinks, default_blueprint=layout)
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
    return recording


def _at(recording: rr.RecordingStream, stamp_ns: int) -> None:
    recording.set_time(TIMELINE, timestamp=np.datetime64(stamp_ns, "ns"))


def log_map(recording: rr.RecordingStream, cloud: MapCloud) -> None:
    """The map's occupied voxels, once (static); the world's up axis (the coordinate axis nearest the map's
    up); and the layout again with the 3-D view looking down on the map from above one corner."""
    points = cloud.points.numpy()
    recording.log(MAP, rr.Points3D(points, colors=cloud.colours.numpy(), radii=0.5 * cloud.voxel), static=True)
    up = np.asarray(cloud.up)
    axis = int(np.abs(up).argmax())
    sign = 1.0 if up[axis] > 0 else -1.0
    coordinates = getattr(rr.ViewCoordinates, f"RIGHT_HAND_{'XYZ'[axis]}_{'UP' if sign > 0 else 'DOWN'}")
    recording.log("world", coordinates, static=True)
    low, high = points.min(0), points.max(0)
    centre, size = (low + high) / 2, high - low
    across = [a for a in range(3) if a != axis]
    eye = centre.copy()
    eye[across[0]] += 0.45 * size[across[0]]
    eye[across[1]] += 0.75 * size[across[1]]
    eye[axis] += sign * 0.9 * max(size[across[0]], size[across[1]])
    recording.send_blueprint(blueprint((eye, centre, np.eye(3)[axis] * sign)))


def _pinhole(intrinsics: PinholeIntrinsics, colour: tuple[int, int, int], plane: float) -> rr.Pinhole:
    return rr.Pinhole(
        focal_length=[intrinsics.fx, intrinsics.fy],
        principal_point=[intrinsics.cx + 0.5, intrinsics.cy + 0.5],  # rerun puts pixel centres at half-integers
        resolution=[intrinsics.width, intrinsics.height],
        camera_xyz=rr.ViewCoordinates.RUB,
        image_plane_distance=plane,
        color=colour,
    )


def log_cameras(recording: rr.RecordingStream, intrinsics: PinholeIntrinsics, plane: float) -> None:
    """The frustums of the estimated and the true camera (static: the camera does not change)."""
    recording.log(f"{ESTIMATE}/camera", _pinhole(intrinsics, ESTIMATE_COLOUR, plane), static=True)
    recording.log(f"{TRUTH}/camera", _pinhole(intrinsics, TRUTH_COLOUR, plane), static=True)


def _log_pose(recording: rr.RecordingStream, entity: str, message: PoseStamped) -> None:
    pose = np.asarray(message.T_world_cam, dtype=np.float64)
    _at(recording, message.stamp_ns)
    recording.log(entity, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))


def log_estimate(recording: rr.RecordingStream, estimate: PoseEstimate, error: tuple[float, float] | None) -> None:
    """The filter's pose, its spread, particle count and effective sample size, and its (translation m, rotation °) error when known."""
    _log_pose(recording, ESTIMATE, estimate)
    recording.log("filter/spread_m", rr.Scalars(estimate.spread))
    recording.log("filter/particles", rr.Scalars(estimate.particle_count))
    recording.log("filter/effective_sample_size", rr.Scalars(estimate.effective_sample_size))
    if error is not None:
        recording.log("error/translation_m", rr.Scalars(error[0]))
        recording.log("error/rotation_deg", rr.Scalars(error[1]))


def log_truth(recording: rr.RecordingStream, truth: PoseStamped) -> None:
    """The true camera pose."""
    _log_pose(recording, TRUTH, truth)


def log_trajectory(recording: rr.RecordingStream, which: str, stamp_ns: int, positions: np.ndarray) -> None:
    """The path so far, positions (N, 3), as one line (``which``: estimate or truth)."""
    _at(recording, stamp_ns)
    colour = ESTIMATE_COLOUR if which == "estimate" else TRUTH_COLOUR
    recording.log(f"world/trajectory/{which}", rr.LineStrips3D([positions], colors=[colour], radii=rr.Radius.ui_points(1.5)))


def log_particles(recording: rr.RecordingStream, cloud: ParticleCloud) -> None:
    """Particle positions, coloured from dark (light) to bright yellow (the heaviest)."""
    _at(recording, cloud.stamp_ns)
    weights = np.asarray(cloud.weights, dtype=np.float64)
    shade = weights / weights.max() if len(weights) and weights.max() > 0 else np.zeros_like(weights)
    colours = np.stack([80 + 175 * shade, 80 + 160 * shade, 200 - 160 * shade], axis=-1).astype(np.uint8)
    positions = np.asarray(cloud.positions, dtype=np.float32).reshape(-1, 3)
    recording.log(PARTICLES, rr.Points3D(positions, colors=colours, radii=rr.Radius.ui_points(3.5)))


def log_status(recording: rr.RecordingStream, status: FilterStatus) -> None:
    """Measured rates (Hz) and the update latency (s)."""
    _at(recording, status.stamp_ns)
    for name, rate in status.rates_hz.items():
        recording.log(f"rates/{name}", rr.Scalars(rate))
    if status.update_latency_s is not None:
        recording.log("filter/update_latency_s", rr.Scalars(status.update_latency_s))


def log_images(recording: rr.RecordingStream, stamp_ns: int, camera: np.ndarray, render: np.ndarray | None) -> None:
    """The camera image (H, W, 3) uint8 (in the 2-D view and in the estimate's frustum) and the map rendered at the estimate."""
    _at(recording, stamp_ns)
    image = rr.Image(camera, color_model="RGB")
    recording.log("camera/image", image)
    recording.log(f"{ESTIMATE}/camera", image)
    if render is not None:
        recording.log("camera/render", rr.Image(render, color_model="RGB"))
