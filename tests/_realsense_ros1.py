"""A RealSense recording as older SDKs wrote it (ROS 1 ``.bag``), written without a camera.

librealsense up to 2.5x recorded ROS 1 bags (file format version 4); that is what every
existing user recording is. This writes one with ``rosbags`` in the layout librealsense's
own reader expects, followed from ``src/media/ros/ros_file_format.h`` (topic names),
``ros_writer.cpp`` (what a recording holds) and ``ros_reader.cpp`` (what playback reads) of
IntelRealSense/librealsense v2.56.5:

- ``/file_version`` (``std_msgs/UInt32`` 4) and every static description at ROS's
  ``TIME_MIN`` (1 ns: the reader refuses time 0);
- ``/device_0/info`` and ``/device_0/sensor_0/info``: ``diagnostic_msgs/KeyValue`` camera
  infos ("Name" "Stereo Module" makes the sensor a depth sensor);
- per stream (``Depth_0``, ``Infrared_1``): ``<stream>/info`` (``realsense_msgs/StreamInfo``:
  fps, encoding ``mono16`` for Z16 / ``8UC1`` for Y8), ``<stream>/info/camera_info``
  (``sensor_msgs/CameraInfo``: K and the distortion model's name), ``<stream>/tf/0``
  (``geometry_msgs/Transform`` to the extrinsics group 0);
- options ``/device_0/sensor_0/option/<Name>/value`` (``std_msgs/Float32``) with their
  ``.../description`` (``std_msgs/String``): "Depth Units" [m] and "Stereo Baseline" [mm];
- frames ``<stream>/image/data`` (``sensor_msgs/Image``; header stamp = the device
  timestamp, seq = frame number) and ``<stream>/image/metadata`` (``KeyValue`` per item),
  at the record time since start.

RealSense's ``std_msgs/Header`` names the third field ``version`` where ROS says
``frame_id``; since v2.49 its writer sets it to "1" on every image and appends the frame's
``depth_units`` (float32 [m]; 0 for a picture) after the image's data (the md5 stays the
standard one). ``image_depth_units_m`` writes that; None (bags of older SDKs) leaves the
reader to fall back on the "Depth Units" option.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from protocols.camera import StereoIntrinsics

__all__ = ["FILE_VERSION", "write_realsense_ros1_bag"]

FILE_VERSION = 4  # ROS_FILE_WITH_RECOMMENDED_PROCESSING_BLOCKS
_TIME_MIN_NS = 1  # rs2rosinternal::TIME_MIN: where a recording keeps what does not change
_STREAM_INFO_MSG = """\
uint32 fps
string encoding
bool is_recommended
"""  # realsense_msgs/StreamInfo (md5 311d7e24eac31bb87271d041bf70ff7d)


def _typestore():
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg(_STREAM_INFO_MSG, "realsense_msgs/msg/StreamInfo"))
    return ts


def write_realsense_ros1_bag(
    path: Path | str,
    k: StereoIntrinsics,
    frames: Iterable[tuple[np.ndarray, np.ndarray | None]],
    *,
    rate_hz: float = 10.0,
    fps: int = 30,
    depth_scale_m: float = 0.001,
    image_depth_units_m: float | None = 0.001,
    first_stamp_ms: float = 1000.0,
) -> None:
    """Write (Z16 depth plane, Y8 infrared 1 picture or None) frames as a RealSense D4xx
    recording: ``rate_hz`` apart in device time [ms from ``first_stamp_ms``] and in record
    time. ``depth_scale_m`` is the depth sensor's "Depth Units" option [m],
    ``image_depth_units_m`` the units each depth image carries (None: none, as before SDK
    2.49); the baseline goes in as the "Stereo Baseline" option [mm]."""
    ts = _typestore()
    T = ts.types
    KeyValue, UInt32 = T["diagnostic_msgs/msg/KeyValue"], T["std_msgs/msg/UInt32"]
    Float32, String = T["std_msgs/msg/Float32"], T["std_msgs/msg/String"]
    StreamInfo, CameraInfo = T["realsense_msgs/msg/StreamInfo"], T["sensor_msgs/msg/CameraInfo"]
    Image, Header, Time = (
        T["sensor_msgs/msg/Image"],
        T["std_msgs/msg/Header"],
        T["builtin_interfaces/msg/Time"],
    )
    Transform, Vector3 = T["geometry_msgs/msg/Transform"], T["geometry_msgs/msg/Vector3"]
    Quaternion, ROI = T["geometry_msgs/msg/Quaternion"], T["sensor_msgs/msg/RegionOfInterest"]

    def time(ns: int):
        return Time(sec=ns // 10**9, nanosec=ns % 10**9)

    sensor = "/device_0/sensor_0"
    streams = {"Depth_0": "mono16", "Infrared_1": "8UC1"}
    with Writer(Path(path)) as bag:
        conns: dict[str, object] = {}

        def write(topic: str, t_ns: int, msg, tail: bytes = b"") -> None:
            if topic not in conns:
                conns[topic] = bag.add_connection(topic, msg.__msgtype__, typestore=ts)
            bag.write(conns[topic], t_ns, bytes(ts.serialize_ros1(msg, msg.__msgtype__)) + tail)

        write("/file_version", _TIME_MIN_NS, UInt32(data=FILE_VERSION))
        for key, value in (
            ("Name", "Intel RealSense D435"),
            ("Serial Number", "000000000000"),
            ("Product Id", "0B07"),
            ("Product Line", "D400"),
        ):
            write("/device_0/info", _TIME_MIN_NS, KeyValue(key=key, value=value))
        write(f"{sensor}/info", _TIME_MIN_NS, KeyValue(key="Name", value="Stereo Module"))
        kk = np.array([k.fx_px, 0, k.cx_px, 0, k.fy_px, k.cy_px, 0, 0, 1], dtype=np.float64)
        identity = Transform(
            translation=Vector3(x=0.0, y=0.0, z=0.0),
            rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        )
        for stream, encoding in streams.items():
            prefix = f"{sensor}/{stream}"
            info = StreamInfo(fps=fps, encoding=encoding, is_recommended=True)
            write(f"{prefix}/info", _TIME_MIN_NS, info)
            camera_info = CameraInfo(
                header=Header(seq=0, stamp=time(0), frame_id=""),
                height=k.height_px,
                width=k.width_px,
                distortion_model="Brown Conrady",
                D=np.zeros(5),
                K=kk,
                R=np.zeros(9),
                P=np.zeros(12),
                binning_x=0,
                binning_y=0,
                roi=ROI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            )
            write(f"{prefix}/info/camera_info", _TIME_MIN_NS, camera_info)
            write(f"{prefix}/tf/0", _TIME_MIN_NS, identity)  # depth is registered to IR 1
        for name, value in (
            ("Depth_Units", depth_scale_m),
            ("Stereo_Baseline", 1000 * k.baseline_m),
        ):
            write(f"{sensor}/option/{name}/value", _TIME_MIN_NS, Float32(data=float(value)))
            text = String(data=f"Read only option of {name.replace('_', ' ')}")
            write(f"{sensor}/option/{name}/description", _TIME_MIN_NS, text)

        period_ns = round(1e9 / rate_hz)
        for i, (plane, picture) in enumerate(frames):
            record_ns = 1_000_000 + i * period_ns
            stamp_ms = first_stamp_ms + i * 1000.0 / rate_hz
            stamp = time(round(stamp_ms * 1e6))
            for stream, pixels in (("Infrared_1", picture), ("Depth_0", plane)):
                if pixels is None:
                    continue
                depth = stream == "Depth_0"
                data = np.ascontiguousarray(pixels, dtype="<u2" if depth else np.uint8)
                with_units = image_depth_units_m is not None
                image = Image(
                    header=Header(seq=i, stamp=stamp, frame_id="1" if with_units else ""),
                    height=data.shape[0],
                    width=data.shape[1],
                    encoding=streams[stream],
                    is_bigendian=0,
                    step=data.shape[1] * data.itemsize,
                    data=data.view(np.uint8).reshape(-1),
                )
                units = image_depth_units_m if depth else 0.0
                tail = struct.pack("<f", units) if with_units else b""
                write(f"{sensor}/{stream}/image/data", record_ns, image, tail)
                for key, value in (
                    ("system_time", f"{stamp_ms:.6f}"),
                    ("timestamp_domain", "Hardware Clock"),
                    ("Frame Counter", str(i)),
                    ("Frame Timestamp", str(round(stamp_ms * 1000))),
                ):
                    metadata = KeyValue(key=key, value=value)
                    write(f"{sensor}/{stream}/image/metadata", record_ns, metadata)
