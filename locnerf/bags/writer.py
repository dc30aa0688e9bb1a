"""Write rosbag2 bags (MCAP storage, which ROS 2's ``ros2 bag`` and Foxglove open) with rosbags.

:class:`BagWriter` writes messages (or their CDR bytes as received) on topics it declares on first
use, with the message definitions of locnerf's type store (nav2_msgs' ParticleCloud included).
:class:`EventWriter` writes locnerf's sensor events with the standard types, under the topic names
:class:`~locnerf.bags.topics.BagTopics` reads by default, so an exported bag replays with no options.
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import TracebackType

import cv2
import torch
from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer

from locnerf.bags.topics import BagTopics, sibling_camera_info
from locnerf.errors import LocnerfInputError
from locnerf.geometry.frames import camera_extrinsic_opencv_to_opengl
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.ros2 import messages as build
from locnerf.ros2.types import CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, ODOMETRY, POSE_STAMPED, TF_MESSAGE, serialize, typestore
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent

logger = logging.getLogger(__name__)

ROSBAG2_VERSION = 8
"""metadata.yaml version written (Jazzy's; Kilted reads it too)."""
LATCHED_TOPICS = ("/tf_static",)
_UNSET = QosTime(0, 0)
LATCHED_QOS = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, _UNSET, _UNSET, QosLiveliness.AUTOMATIC, _UNSET, False)
"""tf2's static broadcaster's QoS (keep last 1, reliable, transient local), offered for /tf_static so that
``ros2 bag play`` latches it for late subscribers."""
COLOUR_FRAME = "camera_optical_frame"
DEPTH_FRAME = "camera_depth_optical_frame"


class BagWriter:
    """A new rosbag2 folder ``path`` (it must not exist) with ``storage`` ``mcap`` (default) or
    ``sqlite3``; use as a context manager.

    Raises:
        LocnerfInputError: ``path`` exists already, or another storage.
    """

    def __init__(self, path: str | Path, storage: str = "mcap") -> None:
        self.path = Path(path)
        if self.path.exists():
            raise LocnerfInputError(f"bag {self.path}: exists already; expected a new folder name (a bag is never overwritten)")
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise LocnerfInputError(f"bag storage {storage!r}: expected one of {sorted(plugins)}")
        self._writer = Writer(self.path, version=ROSBAG2_VERSION, storage_plugin=plugins[storage])
        self._writer.open()
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    def _connection(self, topic: str, ros_type: str) -> Connection:
        connection = self._connections.get(topic)
        if connection is None:
            qos = [LATCHED_QOS] if topic in LATCHED_TOPICS else []
            connection = self._connections[topic] = self._writer.add_connection(topic, ros_type, typestore=typestore(), offered_qos_profiles=qos)
            self.counts[topic] = 0
        elif connection.msgtype != ros_type:
            raise ValueError(f"topic {topic} is {connection.msgtype} in this bag, not {ros_type}")
        return connection

    def write_cdr(self, topic: str, ros_type: str, bag_time_ns: int, cdr: bytes) -> None:
        """Write one message as CDR bytes (e.g. as received over rmw_zenoh) at bag time ``bag_time_ns``."""
        self._writer.write(self._connection(topic, ros_type), bag_time_ns, cdr)
        self.counts[topic] += 1

    def write(self, topic: str, ros_type: str, bag_time_ns: int, message: object) -> None:
        """Serialise ``message`` (a rosbags object of ``ros_type``) and write it."""
        self.write_cdr(topic, ros_type, bag_time_ns, serialize(message, ros_type))

    def close(self) -> None:
        """Finish the MCAP file and write metadata.yaml."""
        self._writer.close()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None) -> None:
        self.close()


class EventWriter:
    """Writes sensor events as ROS 2 messages at their stamps.

    Odometry -> nav_msgs/Odometry (``base_link`` in ``odom``); ground truth -> geometry_msgs/PoseStamped
    in ``map``; an image -> sensor_msgs/Image ``rgb8`` (or CompressedImage with ``compression`` png
    or jpeg) with its CameraInfo, and its depth image as ``16UC1`` millimetres: registered (on the
    colour topic's camera info) when it has the colour camera's intrinsics and pose, else with a
    CameraInfo of its own beside it and its pose on /tf_static (colour optical frame -> depth optical frame).
    The body is the camera (locnerf's OpenGL camera axes): replay with ``T_body_cam`` identity.

    Args:
        bag: where to write.
        topics: topic names (the reader's defaults).
        compression: "" (raw rgb8), "png" or "jpeg".
    """

    def __init__(self, bag: BagWriter, topics: BagTopics | None = None, compression: str = "") -> None:
        if compression not in ("", "png", "jpeg"):
            raise LocnerfInputError(f"image compression {compression!r}: expected '' (raw rgb8), 'png' or 'jpeg'")
        self.bag = bag
        self.topics = topics or BagTopics()
        self.compression = compression
        self._extrinsic_written = False

    def write(self, event: SensorEvent) -> None:
        stamp = nanoseconds_from_seconds(event.stamp)
        topics = self.topics
        if isinstance(event, OdometryEvent):
            self.bag.write(topics.odometry, ODOMETRY, stamp, build.odometry_message(stamp, event.T_odom_body))
        elif isinstance(event, GroundTruthEvent):
            self.bag.write(topics.ground_truth, POSE_STAMPED, stamp, build.pose_stamped_message(stamp, event.T_world_cam))
        elif isinstance(event, ImageEvent):
            self._image(stamp, event)
        else:
            raise TypeError(f"unknown sensor event {type(event).__name__}")

    def _image(self, stamp: int, event: ImageEvent) -> None:
        topics = self.topics
        info = topics.camera_info or sibling_camera_info(topics.image)
        self.bag.write(info, CAMERA_INFO, stamp, build.camera_info_message(stamp, event.intrinsics, COLOUR_FRAME))
        if self.compression:
            bgr = cv2.cvtColor(event.pixels, cv2.COLOR_RGB2BGR)
            ok, encoded = cv2.imencode(".png" if self.compression == "png" else ".jpg", bgr)
            if not ok:
                raise ValueError(f"OpenCV could not encode a {event.pixels.shape} image as {self.compression}")
            image_topic = topics.image.rstrip("/") + "/compressed"
            self.bag.write(image_topic, COMPRESSED_IMAGE, stamp, build.compressed_image_message(stamp, encoded.tobytes(), self.compression, COLOUR_FRAME))
        else:
            self.bag.write(topics.image, IMAGE, stamp, build.image_message(stamp, event.pixels, "rgb8", COLOUR_FRAME))
        depth = event.depth
        if depth is None:
            return
        registered = depth.T_cam_depth is None and depth.intrinsics == event.intrinsics
        frame = COLOUR_FRAME if registered else DEPTH_FRAME
        if not registered:
            self.bag.write(
                topics.depth_camera_info or sibling_camera_info(topics.depth), CAMERA_INFO, stamp, build.camera_info_message(stamp, depth.intrinsics, frame)
            )
            self._write_extrinsic(stamp, depth.T_cam_depth)
        self.bag.write(topics.depth, IMAGE, stamp, build.image_message(stamp, depth.millimetres.astype("<u2"), "16UC1", frame))

    def _write_extrinsic(self, stamp: int, T_cam_depth: torch.Tensor | None) -> None:
        """The depth camera's pose in the colour camera, once, on /tf_static (optical frames: OpenCV axes)."""
        if self._extrinsic_written:
            return
        offset = (
            torch.eye(4, dtype=torch.float64) if T_cam_depth is None else camera_extrinsic_opencv_to_opengl(T_cam_depth.double())
        )  # F·T·F is its own inverse
        transform = build.transform_stamped_message(stamp, COLOUR_FRAME, DEPTH_FRAME, offset)
        self.bag.write("/tf_static", TF_MESSAGE, stamp, build.tf_message([transform]))
        self._extrinsic_written = True
