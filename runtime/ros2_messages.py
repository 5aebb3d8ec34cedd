"""ROS 2 message definitions and a small CDR codec for the sensor log (``runtime.sensorlog``).

The standard types are the real ones of ros2/common_interfaces (``sensor_msgs``, ``nav_msgs``, ``geometry_msgs``,
``std_msgs``, ``tf2_msgs``, ``builtin_interfaces``), written as ``ros2 bag`` writes them into MCAP: the type's
own fields, then each dependency after a line of 80 ``=`` and ``MSG: pkg/Type``. Three types are this project's
own (``p3at_msgs``), for what no standard message carries bit-exactly: the runtime's clock in float64 seconds
(a ``builtin_interfaces/Time`` holds integer nanoseconds), the SIP bytes, and a synthetic camera's observations.

The codec writes XCDR1 little-endian (the encapsulation ROS 2's default middlewares use): primitives aligned to
their size counted from the end of the 4-byte encapsulation header, sequences as a uint32 count then elements.
It is written with numpy: its bytes equal mcap-ros2-support's encoder's, but arrays go in one piece (a frame of
150 synthetic observations: 0.24 ms instead of 11.8 ms), and the reader checks every count against the bytes
left before it allocates. The tests check every type against mcap-ros2-support's decoder and rosbags.
"""
from __future__ import annotations

import struct

import numpy as np

SEPARATOR = "=" * 80

_DEFINITIONS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "geometry_msgs/Transform": "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
                                      "geometry_msgs/Transform transform",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "nav_msgs/Odometry": "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
                         "geometry_msgs/TwistWithCovariance twist",
    "sensor_msgs/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify",
    "sensor_msgs/CameraInfo": "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
                              "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
                              "uint32 binning_y\nsensor_msgs/RegionOfInterest roi",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
    "sensor_msgs/Image": "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
                         "uint8 is_bigendian\nuint32 step\nuint8[] data",
    "sensor_msgs/Range": "uint8 ULTRASOUND=0\nuint8 INFRARED=1\nstd_msgs/Header header\nuint8 radiation_type\n"
                         "float32 field_of_view\nfloat32 min_range\nfloat32 max_range\nfloat32 range\n"
                         "float32 variance",
    # -- this project's own ----------------------------------------------------------------------------------
    "p3at_msgs/RawSip": "# One ARCOS SIP as received, and the odometry the runtime derived from it (the driver\n"
                        "# unwraps ARCOS's wrapping fields and re-bases a new session after a reconnection).\n"
                        "std_msgs/Header header\n"
                        "float64 t  # s, runtime clock, exact (the header stamp is the same instant in whole ns)\n"
                        "uint8[] payload  # the SIP payload, packet type byte first, no header or checksum\n"
                        "float64 x  # m, odometry frame\nfloat64 y\nfloat64 theta  # rad\n"
                        "float64 v  # m/s\nfloat64 w  # rad/s\nbool stalled",
    "p3at_msgs/FrameStamp": "# A stereo frame's exact stamp and counter (its images carry the same header stamp)\n"
                            "std_msgs/Header header\nuint64 seq\nfloat64 t  # s, runtime clock, exact",
    "p3at_msgs/StereoObservations": "# Triangulated stereo points of one frame, in base_link\n"
                                    "std_msgs/Header header\nuint64 seq\nfloat64 t  # s, runtime clock, exact\n"
                                    "uint32 count  # N\nuint32 descriptor_size  # D\n"
                                    "float64[] points  # (N, 3) row-major, m\n"
                                    "float64[] covariances  # (N, 3, 3), m^2\n"
                                    "float32[] descriptors  # (N, D)\nfloat64[] pixels  # (N, 2) left image, px",
}
_DEPENDENCIES = {
    "builtin_interfaces/Time": [], "std_msgs/Header": ["builtin_interfaces/Time"],
    "geometry_msgs/Point": [], "geometry_msgs/Vector3": [], "geometry_msgs/Quaternion": [],
    "geometry_msgs/Pose": ["geometry_msgs/Point", "geometry_msgs/Quaternion"],
    "geometry_msgs/PoseWithCovariance": ["geometry_msgs/Pose"],
    "geometry_msgs/Twist": ["geometry_msgs/Vector3"],
    "geometry_msgs/TwistWithCovariance": ["geometry_msgs/Twist"],
    "geometry_msgs/Transform": ["geometry_msgs/Vector3", "geometry_msgs/Quaternion"],
    "geometry_msgs/TransformStamped": ["std_msgs/Header", "geometry_msgs/Transform"],
    "tf2_msgs/TFMessage": ["geometry_msgs/TransformStamped"],
    "nav_msgs/Odometry": ["std_msgs/Header", "geometry_msgs/PoseWithCovariance", "geometry_msgs/TwistWithCovariance"],
    "sensor_msgs/RegionOfInterest": [],
    "sensor_msgs/CameraInfo": ["std_msgs/Header", "sensor_msgs/RegionOfInterest"],
    "sensor_msgs/CompressedImage": ["std_msgs/Header"], "sensor_msgs/Image": ["std_msgs/Header"],
    "sensor_msgs/Range": ["std_msgs/Header"],
    "p3at_msgs/RawSip": ["std_msgs/Header"], "p3at_msgs/FrameStamp": ["std_msgs/Header"],
    "p3at_msgs/StereoObservations": ["std_msgs/Header"],
}


def _closure(name: str) -> list[str]:
    seen: list[str] = []

    def visit(n: str) -> None:
        for d in _DEPENDENCIES[n]:
            if d not in seen:
                seen.append(d)
                visit(d)
    visit(name)
    return seen


def message_definition(name: str) -> str:
    """The concatenated ``ros2msg`` text of ``pkg/Type`` and its dependencies (the MCAP schema's data)."""
    parts = [_DEFINITIONS[name]] + [f"{SEPARATOR}\nMSG: {d}\n{_DEFINITIONS[d]}" for d in _closure(name)]
    return "\n".join(parts) + "\n"


def schema_name(name: str) -> str:
    """``pkg/msg/Type``, as ROS 2 names a type in a bag's schema."""
    package, type_name = name.split("/")
    return f"{package}/msg/{type_name}"


TYPES = tuple(_DEFINITIONS)


# -- what ``ros2 bag play`` needs besides the messages ---------------------------------------------------------
LATCHED_TOPICS = frozenset({"/tf_static"})   # published transient-local, as tf2's StaticTransformBroadcaster does


def offered_qos_profiles(topic: str) -> str:
    """The ``offered_qos_profiles`` text of a channel (MCAP's ``ros2`` profile requires it in each channel's metadata):
    the QoS the recorded publisher offered, which ``ros2 bag play`` offers again. Without it the player offers its
    default, volatile, and tf2's listeners, which ask for transient-local on ``/tf_static``, receive none of the
    camera and sonar mounts (ros2/rviz#916, ros2/rosbag2#1049). Reliable (a reliable offer serves reliable and
    best-effort subscribers alike), keep-last, durations unspecified (0: the middleware's defaults).

    Written as rosbag2 writes it up to metadata version 8 (Humble, Iron): a YAML list, the policies as integers
    (rmw's enums: history keep-last 1; reliability reliable 1; durability transient-local 1, volatile 2; liveliness
    automatic 1). Humble reads only integers; later rosbag2 reads integers from a file whose ``rosbag2`` metadata
    record (:data:`ROSBAG2_METADATA`) carries no serialized metadata, as every segment's does."""
    latched = topic in LATCHED_TOPICS
    zero = "\n    sec: 0\n    nsec: 0"
    return (f"- history: 1\n  depth: {1 if latched else 10}\n  reliability: 1\n  durability: {1 if latched else 2}\n"
            f"  deadline:{zero}\n  lifespan:{zero}\n  liveliness: 1\n  liveliness_lease_duration:{zero}\n"
            "  avoid_ros_namespace_conventions: false")


def channel_metadata(topic: str) -> dict[str, str]:
    """The metadata of a sensor-log channel (MCAP ``ros2`` profile): its offered QoS."""
    return {"offered_qos_profiles": offered_qos_profiles(topic)}


# the MCAP metadata record rosbag2 looks for: with empty serialized metadata it reads the channels' QoS as a bag of
# metadata version 8 (integers), see offered_qos_profiles
ROSBAG2_METADATA = ("rosbag2", {"serialized_metadata": ""})


# -- encoding -----------------------------------------------------------------------------------------------
class CdrWriter:
    """XCDR1 little-endian; ``bytes()`` gives the message with its encapsulation header."""

    def __init__(self) -> None:
        self._parts: list[bytes] = [b"\x00\x01\x00\x00"]
        self._offset = 0

    def _align(self, size: int) -> None:
        pad = -self._offset % size
        if pad:
            self._parts.append(b"\x00" * pad)
            self._offset += pad

    def _put(self, fmt: str, size: int, value) -> None:
        self._align(size)
        self._parts.append(struct.pack("<" + fmt, value))
        self._offset += size

    def int32(self, v: int) -> None:
        self._put("i", 4, v)

    def uint32(self, v: int) -> None:
        self._put("I", 4, v)

    def uint64(self, v: int) -> None:
        self._put("Q", 8, v)

    def uint8(self, v: int) -> None:
        self._put("B", 1, v)

    def float32(self, v: float) -> None:
        self._put("f", 4, v)

    def float64(self, v: float) -> None:
        self._put("d", 8, v)

    def string(self, s: str) -> None:
        data = s.encode() + b"\x00"
        self.uint32(len(data))
        self._parts.append(data)
        self._offset += len(data)

    def array(self, values, dtype: str, fixed: int | None = None) -> None:
        """A sequence (``fixed`` None: count first) or a fixed array of ``dtype`` ('<f8', '<f4', 'u1')."""
        a = np.ascontiguousarray(values, dtype=np.dtype(dtype)).reshape(-1)
        if fixed is None:
            self.uint32(len(a))
        elif len(a) != fixed:
            raise ValueError(f"a fixed array of {fixed} elements was given {len(a)}")
        if len(a):
            self._align(a.itemsize)
            self._parts.append(a.tobytes())
            self._offset += a.nbytes

    def raw_bytes(self, data: bytes) -> None:
        """A ``uint8[]`` sequence from bytes."""
        self.uint32(len(data))
        self._parts.append(bytes(data))
        self._offset += len(data)

    def header(self, stamp_ns: int, frame_id: str) -> None:
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        self.int32(sec)
        self.uint32(nanosec)
        self.string(frame_id)

    def __bytes__(self) -> bytes:
        return b"".join(self._parts)


class CdrError(ValueError):
    """A message's bytes do not hold what its type says (too short, a count beyond the data, bad text)."""


class CdrReader:
    """Reads what :class:`CdrWriter` writes; every count is checked against the bytes left before use."""

    def __init__(self, data: bytes) -> None:
        if len(data) < 4 or data[:2] != b"\x00\x01":
            raise CdrError("not little-endian CDR (encapsulation header 00 01 expected)")
        self._data = memoryview(data)[4:]
        self._offset = 0

    def _align(self, size: int) -> None:
        self._offset += -self._offset % size

    def _get(self, fmt: str, size: int):
        self._align(size)
        if self._offset + size > len(self._data):
            raise CdrError("message ends early")
        value = struct.unpack_from("<" + fmt, self._data, self._offset)[0]
        self._offset += size
        return value

    def int32(self) -> int:
        return self._get("i", 4)

    def uint32(self) -> int:
        return self._get("I", 4)

    def uint64(self) -> int:
        return self._get("Q", 8)

    def uint8(self) -> int:
        return self._get("B", 1)

    def float32(self) -> float:
        return self._get("f", 4)

    def float64(self) -> float:
        return self._get("d", 8)

    def string(self, limit: int = 4096) -> str:
        n = self.uint32()
        if n == 0 or n > limit or self._offset + n > len(self._data):
            raise CdrError(f"a string of {n} bytes does not fit the message (or exceeds {limit})")
        raw = bytes(self._data[self._offset:self._offset + n])
        self._offset += n
        if raw[-1] != 0:
            raise CdrError("a string is not NUL-terminated")
        try:
            return raw[:-1].decode()
        except UnicodeDecodeError:
            raise CdrError("a string is not UTF-8") from None

    def array(self, dtype: str, fixed: int | None = None) -> np.ndarray:
        dt = np.dtype(dtype)
        n = self.uint32() if fixed is None else fixed
        if n == 0:
            return np.zeros(0, dt)
        self._align(dt.itemsize)
        if n * dt.itemsize > len(self._data) - self._offset:
            raise CdrError(f"a sequence of {n} elements runs past the end of the message")
        out = np.frombuffer(self._data, dt, n, self._offset).copy()
        self._offset += n * dt.itemsize
        return out

    def raw_bytes(self) -> bytes:
        return self.array("u1").tobytes()

    def header(self) -> tuple[int, str]:
        sec, nanosec = self.int32(), self.uint32()
        if nanosec >= 1_000_000_000:
            raise CdrError(f"header stamp nanosec {nanosec} is not below 1e9")
        return sec * 1_000_000_000 + nanosec, self.string()


# -- the messages the sensor log writes ---------------------------------------------------------------------
def stamp_ns(t: float) -> int:
    """Integer nanoseconds of a runtime-clock time in seconds (header stamps, MCAP log times)."""
    return round(float(t) * 1e9)


def yaw_quaternion(theta: float) -> tuple[float, float, float, float]:
    return 0.0, 0.0, float(np.sin(theta / 2.0)), float(np.cos(theta / 2.0))


def matrix_quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (3, 3), w >= 0."""
    R = np.asarray(R, float)
    w = np.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2.0
    x = np.copysign(np.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2.0, R[2, 1] - R[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2.0, R[0, 2] - R[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2.0, R[1, 0] - R[0, 1])
    return float(x), float(y), float(z), float(w)


def encode_odometry(ns: int, frame: str, child: str, x: float, y: float, theta: float, v: float, w: float,
                    pose_covariance: np.ndarray, twist_covariance: np.ndarray) -> bytes:
    """A nav_msgs/Odometry; ``pose_covariance`` and ``twist_covariance`` (6, 6) over (x, y, z, rotation about X, Y,
    Z), written row-major (geometry_msgs/PoseWithCovariance, TwistWithCovariance). runtime/sensorlog.py's
    ``OdometryCovariance`` makes them: an all-zero matrix would claim a perfectly known pose."""
    c = CdrWriter()
    c.header(ns, frame)
    c.string(child)
    for value in (x, y, 0.0, *yaw_quaternion(theta)):
        c.float64(value)
    c.array(np.asarray(pose_covariance, float).reshape(36), "<f8", 36)
    for value in (v, 0.0, 0.0, 0.0, 0.0, w):
        c.float64(value)
    c.array(np.asarray(twist_covariance, float).reshape(36), "<f8", 36)
    return bytes(c)


def encode_transforms(ns: int, transforms: list[tuple[str, str, np.ndarray]]) -> bytes:
    """A TFMessage; each transform (parent, child, T (4, 4) child -> parent)."""
    c = CdrWriter()
    c.uint32(len(transforms))
    for parent, child, T in transforms:
        c.header(ns, parent)
        c.string(child)
        for value in (*T[:3, 3], *matrix_quaternion(T[:3, :3])):
            c.float64(value)
    return bytes(c)


def encode_range(ns: int, frame: str, field_of_view: float, min_range: float, max_range: float,
                 value: float) -> bytes:
    c = CdrWriter()
    c.header(ns, frame)
    c.uint8(0)  # ULTRASOUND
    for v in (field_of_view, min_range, max_range, value, 0.0):
        c.float32(v)
    return bytes(c)


def encode_camera_info(ns: int, frame: str, width: int, height: int, K: np.ndarray, P: np.ndarray) -> bytes:
    """A rectified camera's CameraInfo: no distortion, identity R, projection P (3, 4)."""
    c = CdrWriter()
    c.header(ns, frame)
    c.uint32(height)
    c.uint32(width)
    c.string("plumb_bob")
    c.array(np.zeros(5), "<f8")
    c.array(K, "<f8", 9)
    c.array(np.eye(3), "<f8", 9)
    c.array(P, "<f8", 12)
    for v in (0, 0, 0, 0, 0, 0):  # binning x/y, roi x/y offset, height, width (0: full image)
        c.uint32(v)
    c.uint8(0)
    return bytes(c)


def encode_compressed_image(ns: int, frame: str, fmt: str, data: bytes) -> bytes:
    c = CdrWriter()
    c.header(ns, frame)
    c.string(fmt)
    c.raw_bytes(data)
    return bytes(c)


def encode_image(ns: int, frame: str, image: np.ndarray) -> bytes:
    image = np.ascontiguousarray(image, np.uint8)
    c = CdrWriter()
    c.header(ns, frame)
    c.uint32(image.shape[0])
    c.uint32(image.shape[1])
    c.string("mono8" if image.ndim == 2 else "bgr8")
    c.uint8(0)
    c.uint32(image.strides[0])
    c.raw_bytes(image.tobytes())
    return bytes(c)


def encode_raw_sip(ns: int, frame: str, t: float, payload: bytes, x: float, y: float, theta: float, v: float,
                   w: float, stalled: bool) -> bytes:
    c = CdrWriter()
    c.header(ns, frame)
    c.float64(t)
    c.raw_bytes(payload)
    for value in (x, y, theta, v, w):
        c.float64(value)
    c.uint8(1 if stalled else 0)
    return bytes(c)


def encode_frame_stamp(ns: int, frame: str, seq: int, t: float) -> bytes:
    c = CdrWriter()
    c.header(ns, frame)
    c.uint64(seq)
    c.float64(t)
    return bytes(c)


def encode_observations(ns: int, frame: str, seq: int, t: float, points: np.ndarray, covariances: np.ndarray,
                        descriptors: np.ndarray, pixels: np.ndarray) -> bytes:
    n = len(points)
    descriptors = np.asarray(descriptors, np.float32)
    width = descriptors.shape[1] if descriptors.ndim == 2 else (descriptors.size // n if n else 0)
    descriptors = descriptors.reshape(n, width)
    c = CdrWriter()
    c.header(ns, frame)
    c.uint64(seq)
    c.float64(t)
    c.uint32(n)
    c.uint32(descriptors.shape[1])
    c.array(points, "<f8")
    c.array(covariances, "<f8")
    c.array(descriptors, "<f4")
    c.array(pixels, "<f8")
    return bytes(c)
