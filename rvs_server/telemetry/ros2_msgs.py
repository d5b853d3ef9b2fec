"""The ROS 2 message definitions a ``ros2`` recording writes (:mod:`.ros2_messages`), as their
.msg files give them (fields and constants; the comments left out), and their CDR encoders.

A schema in an MCAP file of the ``ros2`` profile is the type's own definition followed by every
type it depends on, each under a ``MSG: pkg/Type`` line after a line of 80 ``=``, as rosbag2
writes it: a reader (``ros2 bag play``, Foxglove, ``mcap_ros2``) needs no ROS installation to
decode the file. The CDR encoding is mcap-ros2-support's, built from the same text, so what is
written and what is declared cannot differ.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from functools import cache
from typing import Any

from mcap_ros2._dynamic import serialize_dynamic  # the encoder its Writer uses, without that writer's file

SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
SEPARATOR = "=" * 80

# pkg/Type (as a dependency names it) -> its definition
DEFINITIONS = {
    "builtin_interfaces/Time": """
int32 sec
uint32 nanosec
""",
    "std_msgs/Header": """
builtin_interfaces/Time stamp
string frame_id
""",
    "std_msgs/String": """
string data
""",
    "std_msgs/MultiArrayDimension": """
string label
uint32 size
uint32 stride
""",
    "std_msgs/MultiArrayLayout": """
MultiArrayDimension[] dim
uint32 data_offset
""",
    "std_msgs/Float32MultiArray": """
MultiArrayLayout layout
float32[] data
""",
    "geometry_msgs/Point": """
float64 x
float64 y
float64 z
""",
    "geometry_msgs/Vector3": """
float64 x
float64 y
float64 z
""",
    "geometry_msgs/Quaternion": """
float64 x 0
float64 y 0
float64 z 0
float64 w 1
""",
    "geometry_msgs/Pose": """
Point position
Quaternion orientation
""",
    "geometry_msgs/PoseStamped": """
std_msgs/Header header
Pose pose
""",
    "geometry_msgs/Transform": """
Vector3 translation
Quaternion rotation
""",
    "geometry_msgs/TransformStamped": """
std_msgs/Header header
string child_frame_id
Transform transform
""",
    "tf2_msgs/TFMessage": """
geometry_msgs/TransformStamped[] transforms
""",
    "nav_msgs/Path": """
std_msgs/Header header
geometry_msgs/PoseStamped[] poses
""",
    "sensor_msgs/PointField": """
uint8 INT8    = 1
uint8 UINT8   = 2
uint8 INT16   = 3
uint8 UINT16  = 4
uint8 INT32   = 5
uint8 UINT32  = 6
uint8 FLOAT32 = 7
uint8 FLOAT64 = 8
string name
uint32 offset
uint8  datatype
uint32 count
""",
    "sensor_msgs/PointCloud2": """
std_msgs/Header header
uint32 height
uint32 width
PointField[] fields
bool    is_bigendian
uint32  point_step
uint32  row_step
uint8[] data
bool is_dense
""",
    "sensor_msgs/Image": """
std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data
""",
    "sensor_msgs/CompressedImage": """
std_msgs/Header header
string format
uint8[] data
""",
    "rcl_interfaces/Log": """
byte DEBUG=10
byte INFO=20
byte WARN=30
byte ERROR=40
byte FATAL=50
builtin_interfaces/Time stamp
uint8 level
string name
string msg
string file
string function
uint32 line
""",
    "grid_map_msgs/GridMapInfo": """
float64 resolution
float64 length_x
float64 length_y
geometry_msgs/Pose pose
""",
    "grid_map_msgs/GridMap": """
std_msgs/Header header
GridMapInfo info
string[] layers
string[] basic_layers
std_msgs/Float32MultiArray[] data
uint16 outer_start_index
uint16 inner_start_index
""",
}

PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
              "int64", "uint64", "string", "wstring"}


def type_name(short: str) -> str:
    """``pkg/Type`` as a schema names it: ``pkg/msg/Type``."""
    pkg, name = short.split("/")
    return f"{pkg}/msg/{name}"


def _dependencies(short: str) -> list[str]:
    """The types ``short``'s fields name directly, as ``pkg/Type``, in field order."""
    pkg = short.split("/")[0]
    out = []
    for line in DEFINITIONS[short].strip().splitlines():
        field_type = line.split()[0]
        if "=" in line or re.sub(r"\[.*\]$|<=\d+$", "", field_type) in PRIMITIVES:
            continue
        base = re.sub(r"\[.*\]$", "", field_type)
        out.append(base if "/" in base else f"{pkg}/{base}")
    return out


@cache
def definition(short: str) -> str:
    """The schema text of ``short`` (``pkg/Type``): its definition, then each type it depends on,
    depth first, once."""
    seen: list[str] = []

    def visit(name: str) -> None:
        for dep in _dependencies(name):
            if dep not in seen:
                seen.append(dep)
                visit(dep)

    visit(short)
    parts = [DEFINITIONS[short].strip()]
    parts += [f"{SEPARATOR}\nMSG: {dep}\n{DEFINITIONS[dep].strip()}" for dep in seen]
    return "\n".join(parts) + "\n"


@cache
def encoder(short: str) -> Callable[[dict[str, Any]], bytes]:
    """The CDR encoder of ``short`` (``pkg/Type``): a message as nested dicts -> its bytes."""
    return serialize_dynamic(type_name(short), definition(short))[type_name(short)]
