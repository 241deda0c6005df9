"""The shipped RViz2 config and Foxglove layout name pivotd's real topics, frame, marker namespaces and QoS."""

import json
import re

import yaml
from support import REPO

from pivotd.bus.markers import NAMESPACES
from pivotd.bus.topics import resolve_topic
from pivotd.config import Config

CFG = Config()
MARKERS = resolve_topic(CFG.ros.markers_topic, CFG.topics.namespace)
TOPICS = {CFG.topics.pose, CFG.topics.path, CFG.topics.landmarks, CFG.topics.targets, CFG.topics.joint_states,
          CFG.topics.view_plan, MARKERS, resolve_topic(CFG.ros.tf_topic, CFG.topics.namespace)}
PUBLISHED_QOS = {CFG.topics.view_plan: CFG.ros.qos.view_plan, MARKERS: CFG.ros.qos.markers,
                 CFG.topics.joint_states: CFG.ros.qos.joint_states}


def test_rviz_config_matches_the_defaults():
    doc = yaml.safe_load((REPO / "config" / "pivotd.rviz").read_text())
    vm = doc["Visualization Manager"]
    assert vm["Global Options"]["Fixed Frame"] == CFG.topics.frame_id
    displays = {d["Class"].split("/")[-1]: d for d in vm["Displays"] if "Topic" in d}
    shown = {d["Topic"]["Value"] for d in vm["Displays"] if "Topic" in d}
    assert shown <= TOPICS and {MARKERS, CFG.topics.view_plan} <= shown
    assert set(displays["MarkerArray"]["Namespaces"]) == set(NAMESPACES)
    for d in vm["Displays"]:
        topic = d.get("Topic")
        if not topic or topic["Value"] not in PUBLISHED_QOS:
            continue
        qos = PUBLISHED_QOS[topic["Value"]]
        # A transient-local reader needs a transient-local writer (DDS QoS matching); a volatile one takes either.
        if topic["Durability Policy"] == "Transient Local":
            assert qos.transient_local, topic
        if topic["Reliability Policy"] == "Reliable":  # likewise a reliable reader needs a reliable writer
            assert qos.reliable, topic


def test_foxglove_layout_matches_the_defaults():
    doc = json.loads((REPO / "config" / "pivotd.foxglove.json").read_text())
    panels = doc["configById"]
    three_d = next(v for k, v in panels.items() if k.startswith("3D!"))
    assert three_d["followTf"] == CFG.topics.frame_id
    assert set(three_d["topics"]) <= TOPICS and MARKERS in three_d["topics"]
    paths = [p["value"] for k, v in panels.items() if k.startswith("Plot!") for p in v["paths"]]
    paths += [v["topicPath"] for k, v in panels.items() if k.startswith("RawMessages!")]
    for path in paths:
        topic = re.match(r"(/[\w/]+)", path)[1]
        assert topic in TOPICS, path

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert set(leaves(doc["layout"])) == set(panels)
