"""The QoS a sensor log's channels say they were offered (MCAP's ``ros2`` profile requires ``offered_qos_profiles``;
``ros2 bag play`` offers it again): read with rosbags' own rosbag2 QoS parser, ``/tf_static`` is transient-local (tf2's
listeners ask for it, and receive nothing from a volatile publisher), every other topic volatile, all reliable."""
from __future__ import annotations

import pytest
import yaml
from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.rosbag2.metadata import parse_qos

from runtime import ros2_messages as ros

TOPICS = ["/tf_static", "/tf", "/robot1/odom", "/robot1/sip", "/robot1/stereo/left/image_rect/compressed",
          "/robot1/stereo/left/camera_info", "/robot1/sonar/sonar_0", "/robot1/stereo/observations"]


@pytest.mark.parametrize("topic", TOPICS)
def test_rosbags_reads_the_offered_qos_as_rosbag2_would_replay_it(topic):
    (qos,) = parse_qos(ros.channel_metadata(topic)["offered_qos_profiles"])
    latched = topic == "/tf_static"
    assert qos.durability == (QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE)
    assert qos.reliability == QosReliability.RELIABLE
    assert qos.history == QosHistory.KEEP_LAST and qos.depth == (1 if latched else 10)
    assert qos.liveliness == QosLiveliness.AUTOMATIC and not qos.avoid_ros_namespace_conventions
    assert (qos.deadline.sec, qos.deadline.nsec, qos.lifespan.sec, qos.liveliness_lease_duration.nsec) == (0,) * 4


def test_the_profiles_are_rosbag2_version_8_yaml_integers_that_humble_reads():
    """Humble's rosbag2 decodes each policy with ``as<int>()``: a name ("reliable") would stop ``ros2 bag play``."""
    (profile,) = yaml.safe_load(ros.offered_qos_profiles("/tf_static"))
    assert set(profile) == {"history", "depth", "reliability", "durability", "deadline", "lifespan", "liveliness",
                            "liveliness_lease_duration", "avoid_ros_namespace_conventions"}
    assert all(isinstance(profile[k], int) for k in ("history", "reliability", "durability", "liveliness"))
    name, record = ros.ROSBAG2_METADATA
    assert name == "rosbag2" and record == {"serialized_metadata": ""}   # read as version 8 by later rosbag2


def test_a_written_log_declares_each_topics_qos_to_rosbags_reader(tmp_path):
    """End to end: a log ``p3at run --log-sensors`` writes carries the profiles in its channels, and the ``rosbag2``
    metadata record that makes rosbag2 read them as version 8 (integers)."""
    import numpy as np
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    from runtime.sensorlog import SensorLog
    from tests.runtime.test_sensorlog_mcap import _records, _write

    _write(tmp_path / "log", _records(20, np.random.default_rng(5)), segment_seconds=100.0)
    (segment,) = SensorLog(tmp_path / "log").files
    with AnyReader([segment]) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert all(len(profiles) == 1 for profiles in qos.values()), qos
    assert qos["/tf_static"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert {p[0].durability for t, p in qos.items() if t != "/tf_static"} == {QosDurability.VOLATILE}
    with open(segment, "rb") as f:
        assert "rosbag2" in {m.name for m in make_reader(f).get_summary().metadata_indexes}
