"""A recording read back as a Foxglove app reads it: every message decoded with the file's own
schemas (protobuf FileDescriptorSets, or JSON)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from scipy.spatial.transform import Rotation

from rvs_server.telemetry.recording import read_messages


def decoded(path: Path) -> list[tuple[str, int, Any]]:
    """(topic, log time, message) of every message in file order."""
    classes: dict[int, Any] = {}
    out = []
    for schema, channel, message in read_messages(path):
        if channel.message_encoding == "json":
            out.append((channel.topic, message.log_time, json.loads(message.data)))
            continue
        if schema.id not in classes:
            pool = descriptor_pool.DescriptorPool()
            for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                pool.Add(f)
            classes[schema.id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
        out.append((channel.topic, message.log_time, classes[schema.id].FromString(message.data)))
    return out


def transform_matrix(tf: Any) -> np.ndarray:
    """A foxglove.FrameTransform as the 4 x 4 pose of its child in its parent."""
    T = np.eye(4)
    q = tf.rotation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return T


def grid_fields(grid: Any) -> dict[str, np.ndarray]:
    """A float32 foxglove.Grid's fields as arrays, rows north first as the server's maps hold them."""
    assert all(f.type == 7 for f in grid.fields)  # FLOAT32
    cells = np.frombuffer(grid.data, np.float32).reshape(-1, grid.column_count, len(grid.fields))
    return {f.name: np.flipud(cells[..., f.offset // 4]) for f in grid.fields}
