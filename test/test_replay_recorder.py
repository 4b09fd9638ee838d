"""replay and recorder as installed executables, through Fast DDS (the node test harness)."""

from __future__ import annotations

import signal

import numpy as np
import pytest
from harness import start

from pose4d_ros.datasets import bag


def _image_bag(path, frames: int = 12, size=(24, 32)):
    """A small bag of rgb8 + 16UC1 images, 30 fps, written with our own bag writer."""
    ts = bag.typestore()
    Image = ts.types['sensor_msgs/msg/Image']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']
    rng = np.random.default_rng(0)
    h, w = size
    t0 = 1_700_000_000_000_000_000
    with bag.BagWriter(path) as writer:
        writer.add_topic('/camera/color/image_raw', 'sensor_msgs/msg/Image')
        writer.add_topic('/camera/depth/image_raw', 'sensor_msgs/msg/Image', [bag.QOS_SENSOR])
        for k in range(frames):
            stamp = t0 + k * 33_333_333
            header = Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9),
                            frame_id='camera_color_optical_frame')
            rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
            depth = rng.integers(0, 4000, (h, w), dtype=np.uint16)
            writer.write('/camera/color/image_raw', stamp, Image(
                header=header, height=h, width=w, encoding='rgb8', is_bigendian=0, step=w * 3,
                data=rgb.ravel()))
            writer.write('/camera/depth/image_raw', stamp, Image(
                header=header, height=h, width=w, encoding='16UC1', is_bigendian=0, step=w * 2,
                data=depth.view(np.uint8).ravel()))
    return path


def _payloads(path):
    return [(m.topic, m.data) for m in bag.read_messages(path)]


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_replay_to_recorder_round_trip(tmp_path, sig):
    source = _image_bag(tmp_path / 'source')
    out = tmp_path / 'recorded'
    topics = ['camera/color/image_raw', 'camera/depth/image_raw']
    recorder = start('recorder', {'recorder.output': str(out), 'recorder.topics': topics},
                     log_dir=tmp_path)
    try:
        replay = start('replay', {'replay.bag': str(source), 'replay.rate': 1.0,
                                  'replay.wait_for_subscribers': ['*=1']}, log_dir=tmp_path)
        assert replay.wait(30) == 0, replay.output()
        assert 'sent 24 messages' in replay.output()
    finally:
        code = recorder.stop(sig)
    assert code == 0, recorder.output()
    assert out.is_dir() and not list(tmp_path.glob('.recorded.partial*'))
    got = _payloads(out)
    want = _payloads(source)
    # every message, payload bytes identical, order kept per topic
    for topic in ('/camera/color/image_raw', '/camera/depth/image_raw'):
        assert [d for t, d in got if t == topic] == [d for t, d in want if t == topic]
    info = bag.topics(out)
    assert info['/camera/color/image_raw'].msgtype == 'sensor_msgs/msg/Image'
    # the recorder matched the depth topic's best-effort publisher
    assert info['/camera/depth/image_raw'].qos[0].reliability.name == 'BEST_EFFORT'
    assert 'wrote 24 messages' in recorder.output()


def test_replay_paces_by_recorded_stamps(tmp_path):
    source = _image_bag(tmp_path / 'source', frames=30)  # 29 intervals of 1/30 s
    out = tmp_path / 'recorded'
    recorder = start('recorder', {'recorder.output': str(out),
                                  'recorder.topics': ['camera/color/image_raw']},
                     log_dir=tmp_path)
    try:
        replay = start('replay', {'replay.bag': str(source), 'replay.rate': 2.0,
                                  'replay.topics': ['camera/color/*'],
                                  'replay.wait_for_subscribers': ['*=1']}, log_dir=tmp_path)
        assert replay.wait(30) == 0, replay.output()
    finally:
        assert recorder.stop() == 0, recorder.output()
    stamps = np.array([m.timestamp_ns for m in bag.read_messages(out)]) * 1e-9
    assert len(stamps) == 30
    # at rate 2 the 29 intervals of 1/30 s take 29/60 s; receive times follow within jitter
    assert stamps[-1] - stamps[0] == pytest.approx(29 / 60, abs=0.05)
    assert np.median(np.diff(stamps)) == pytest.approx(1 / 60, abs=0.004)


def test_recorder_refuses_existing_output(tmp_path):
    (tmp_path / 'exists').mkdir()
    node = start('recorder', {'recorder.output': str(tmp_path / 'exists')}, log_dir=tmp_path)
    assert node.wait(20) == 2
    assert 'exists already' in node.output()


def test_replay_refuses_missing_bag_and_unknown_topics(tmp_path):
    node = start('replay', {'replay.bag': str(tmp_path / 'nope')}, log_dir=tmp_path)
    assert node.wait(20) == 2
    assert 'no such bag' in node.output()
    source = _image_bag(tmp_path / 'source', frames=1)
    node = start('replay', {'replay.bag': str(source), 'replay.topics': ['nothing/*']},
                 log_dir=tmp_path)
    assert node.wait(20) == 2
    assert 'match none' in node.output()


def test_out_of_range_parameter_is_refused(tmp_path):
    source = _image_bag(tmp_path / 'source', frames=1)
    node = start('replay', {'replay.bag': str(source), 'replay.rate': -1.0}, log_dir=tmp_path)
    assert node.wait(20) == 2
    assert 'replay.rate' in node.output()


def test_subscriber_counts_parse_and_refuse() -> None:
    from pose4d_ros.nodes.params import override_args
    from pose4d_ros.nodes.replay import subscriber_counts

    assert subscriber_counts(['camera/*=1', '/camera/color/camera_info=5']) == [
        ('camera/*', 1), ('camera/color/camera_info', 5)]
    for bad in ('camera/*', '=3', 'camera/*=x', 'camera/*=-1'):
        with pytest.raises(ValueError, match='pattern=count'):
            subscriber_counts([bad])
    assert override_args({'a.b': ['*=1'], 'c': 1.0, 'd': True, 'e': '/x:y'}) == [
        '-p', 'a.b:=["*=1"]', '-p', 'c:=1.0', '-p', 'd:=true', '-p', 'e:="/x:y"']
