"""Scene markers: the scene of every plant without ROS, and a lockstep session
whose recording holds the plant's and the controller's markers at ~30 Hz of simulated time,
and /diagnostics from both nodes."""

from pathlib import Path

import numpy as np
import pytest
from robot_data import needs_erd
from ros_probe import next_domain

from cr_control.core import topics
from cr_control.nodes.markers import (
    BLUE,
    GREEN,
    RED,
    TRAIL_POINTS,
    MarkerBytes,
    Trail,
    arrow,
    line_strip,
    solid,
)
from cr_sim.plant_markers import SURFACE_EVERY
from cr_sim.plants.registry import make_plant
from cr_sim.scene import scene_of

LOCKSTEP_S = 3.0


def test_marker_bytes_equal_rclpy_serialization():
    """The bytes :class:`MarkerBytes` fills read back as the markers rclpy serializes
    (stamps, positions and points refilled twice, a negative second included), and a trail
    is its first point repeated until full, then the last TRAIL_POINTS points."""
    from rclpy.serialization import deserialize_message, serialize_message
    from visualization_msgs.msg import Marker, MarkerArray

    from cr_control.nodes.markers import point

    def build():
        return [line_strip("links", "base", [], 0.01, BLUE), solid("s", Marker.SPHERE, "base",
                (0, 0, 0), (0.02,) * 3, GREEN), arrow("f", "base", (0, 0, 0), (0, 0, 0), RED)]

    rng = np.random.default_rng(3)
    layout = MarkerBytes(build(), [4, 0, 2])
    for sec, nanosec in ((12, 345_678_901), (-3, 999_999_999)):
        links, centre, ends = rng.normal(size=(4, 3)), rng.normal(size=3), rng.normal(size=(2, 3))
        values = np.concatenate([np.zeros(3), links.ravel(), centre, np.zeros(3), ends.ravel()])
        data = layout.fill(values, sec, nanosec)
        expected = build()
        expected[0].points = [point(p) for p in links]
        expected[1].pose.position = point(centre)
        expected[2].points = [point(p) for p in ends]
        for m in expected:
            m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
        # equal field by field (padding bytes may differ: they carry anything)
        reference = serialize_message(MarkerArray(markers=expected))
        assert len(data) == len(reference)
        assert deserialize_message(data, MarkerArray) == deserialize_message(reference, MarkerArray)
    trail = Trail("t", "base", 0.01, GREEN, size=3)
    assert trail.add((1.0, 2.0)).tolist() == [[1.0, 2.0, 0.0]] * 3
    trail.add((3.0, 4.0, 5.0))
    assert trail.add((6.0, 7.0, 8.0)).tolist() == [[1.0, 2.0, 0.0], [3.0, 4.0, 5.0], [6.0, 7.0, 8.0]]
    assert trail.add((9.0, 9.0, 9.0)).tolist() == [[3.0, 4.0, 5.0], [6.0, 7.0, 8.0], [9.0, 9.0, 9.0]]


@pytest.mark.parametrize(("scenario", "surface", "moving"), [
    ("compliant_plane", ["line"], []), ("circular_surface", ["line"], []),
    ("flexible_joint_surface", ["line"], []), ("moving_object", [], ["box", "line"]),
])
def test_scene_of_the_thesis_plants(scenario, surface, moving):
    """Links from the base to the tip (the tip where the plant's model puts it), the surface
    the tip rests on, the force on the tip; 1-D plants have no scene."""
    plant = make_plant(scenario)
    scene = scene_of(plant)
    scene.update()
    assert [s.kind for s in scene.shapes] == surface
    assert [s.kind for s in scene.moving_shapes()] == moving
    links, tip = scene.links(), scene.tip()
    # base origin, (the arm's base at (a, 0) on the moving-object plant,) elbow, tip
    assert links.shape == (4 if scenario == "moving_object" else 3, 3)
    assert np.allclose(links[-1], tip) and np.allclose(links[0], 0.0)
    if scenario == "moving_object":
        assert np.allclose(links[1], [0.2, 0.0, 0.0])
    if scenario in ("compliant_plane", "flexible_joint_surface"):
        line = scene.shapes[0].points
        d = (line[1] - line[0]) / np.linalg.norm(line[1] - line[0])
        off = (tip - line[0]) - ((tip - line[0]) @ d) * d
        # compliant plane: starts touching (zero force); ch. 6: on its rigid line, pressing
        assert np.linalg.norm(off) < 1e-6, np.linalg.norm(off)
    force = scene.force()
    assert force.shape == (3,) and np.isclose(np.linalg.norm(force), plant.contact_force_magnitude())
    for scenario_1d in ("dynamic_constraint", "cmmsd"):
        assert scene_of(make_plant(scenario_1d)) is None


@needs_erd
def test_scene_of_the_panda_on_its_table():
    """The Panda's wiping task (config/robots/panda/plant.yaml): the table as a plane patch
    under the tip, in panda_link0; links from the base through the 7 joints to the tip."""
    import yaml

    from cr_sim.plant_node import NODE_PARAMETERS

    path = Path(__file__).parents[1] / "config" / "robots" / "panda" / "plant.yaml"
    values = yaml.safe_load(path.read_text())["plant"]["ros__parameters"]
    node_only = {p.name for p in NODE_PARAMETERS} | {"scenario"}
    plant = make_plant(values["scenario"], {k: v for k, v in values.items() if k not in node_only})
    scene = scene_of(plant)
    scene.update()
    (table,) = scene.shapes
    links, tip = scene.links(), scene.tip()
    assert scene.frame == "panda_link0" and table.kind == "box"
    assert links.shape == (9, 3) and np.allclose(links[0], 0.0) and np.allclose(links[-1], tip)
    top = table.centre[2] + table.size[2] / 2          # the patch's top face: the table
    assert abs(tip[2] - top) < 0.01 and np.allclose(table.centre[:2], tip[:2])


@pytest.mark.ros
def test_markers_published_at_30_hz_in_a_lockstep_session_and_recorded(tmp_path):
    """adaptive_impedance on the compliant plane, lockstep: /plant/markers and
    /adaptive_impedance/markers are in the MCAP at ~30 Hz of simulated time (stamps), with
    the surface, links, tip trail, force arrow and desired path; /diagnostics from both."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from cr_control.tools.session import Session, SessionConfig

    cfg = SessionConfig(scheme="adaptive_impedance", duration=LOCKSTEP_S, mode="lockstep",
                        out=tmp_path, domain_id=next_domain(), name="run")
    result = Session(cfg, progress=lambda _: None).run()
    plant_topic, ctrl_topic = topics.PLANT_MARKERS, topics.markers_topic("adaptive_impedance")
    got: dict[str, list] = {plant_topic: [], ctrl_topic: [], topics.DIAGNOSTICS: []}
    with open(result.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=list(got)):
            got[channel.topic].append(msg)
    for topic in (plant_topic, ctrl_topic):
        msgs = got[topic]
        stamps = np.array([m.markers[0].header.stamp.sec + 1e-9 * m.markers[0].header.stamp.nanosec
                           for m in msgs])
        rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
        print(f"{topic}: {len(msgs)} MarkerArrays over {stamps[-1] - stamps[0]:.3f} s simulated: "
              f"{rate:.2f} Hz; {len(msgs[-1].markers)} markers, "
              f"{sum(len(m.points) for m in msgs[-1].markers)} points in the last")
        # one per 1/30 s of simulated time, from the first state to the last (1 ms steps)
        assert 29.0 < rate <= 30.5, rate
        assert len(msgs) >= 30 * (LOCKSTEP_S - 0.2)
        assert np.all(np.diff(stamps) > 0)
    namespaces = {m.ns for m in got[plant_topic][-1].markers}
    assert {"links", "tip_path", "contact_force"} <= namespaces, namespaces
    surfaces = [i for i, msg in enumerate(got[plant_topic]) if any(m.ns == "surface" for m in msg.markers)]
    assert surfaces == list(range(0, len(got[plant_topic]), SURFACE_EVERY)), surfaces
    assert {m.ns for m in got[ctrl_topic][-1].markers} == {"desired_path", "desired"}
    trail = next(m for m in got[plant_topic][-1].markers if m.ns == "tip_path")
    assert len(trail.points) == TRAIL_POINTS
    names = {s.name for m in got[topics.DIAGNOSTICS] for s in m.status}
    assert names == {"plant: loop", "adaptive_impedance: control loop"}, names


def test_foxglove_layout_plots_the_fields_it_names():
    """config/foxglove_layout.json: its status indices are the fields its labels name, its
    3-D panel shows the markers topics, and its topics are ones the session records."""
    import json
    import re

    from cr_control.core.parameters import resolve
    from cr_control.schemes.registry import controller_class

    layout = json.loads((Path(__file__).parents[1] / "config" / "foxglove_layout.json").read_text())
    cls = controller_class("adaptive_impedance")
    fields = cls(resolve(cls.parameters(), None)).status_fields + topics.NODE_STATUS_FIELDS
    paths = [p for c in layout["configById"].values() for p in c.get("paths", [])]
    indexed = [(re.fullmatch(r"/adaptive_impedance/status\.data\[(\d+)\]", p["value"]), p["label"])
               for p in paths]
    assert sum(m is not None for m, _ in indexed) == 4
    for match, label in indexed:
        if match:
            assert fields[int(match.group(1))] == label
    scene = layout["configById"]["3D!crscene"]
    assert set(scene["topics"]) == {topics.PLANT_MARKERS, topics.markers_topic("adaptive_impedance")}
    assert {p["value"].split(".")[0] for p in paths} == {topics.WRENCH, "/adaptive_impedance/status"}


@pytest.mark.ros
def test_plant_markers_serialize_every_layout_before_the_loop(ros_env):
    """PlantMarkers.warm_up serializes every layout tick sends (surface or not, force arrow
    or its deletion): driving the compliant plane into and out of contact for more than
    SURFACE_EVERY publishes makes no new one (each first serialization took ~3 ms of a
    1 kHz tick)."""
    import rclpy
    from rclpy.context import Context

    from cr_sim.plant_markers import PlantMarkers

    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = rclpy.create_node("markers_probe", context=context)
    try:
        plant = make_plant("compliant_plane")
        markers = PlantMarkers(node, plant)
        markers.warm_up()
        prepared = set(markers.pub._layouts)
        assert len(prepared) == 4
        sent = []
        markers.pub.pub.publish = lambda data: sent.append(len(data))
        push, pull = np.array([20.0, 20.0]), np.array([-20.0, -20.0])
        for k in range(2 * SURFACE_EVERY + 2):
            for _ in range(34):                    # a marker period (33.3 ms) on
                plant.step(push if k % 4 < 2 else pull, 1e-3)
            markers.tick(plant.time, int(plant.time), 0)
        assert len(sent) == 2 * SURFACE_EVERY + 2
        assert len(set(sent)) == 4                   # all four layouts were sent ...
        assert set(markers.pub._layouts) == prepared  # ... and none was new
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
