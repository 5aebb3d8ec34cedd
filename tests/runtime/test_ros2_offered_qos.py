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
