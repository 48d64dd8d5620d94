"""The live Foxglove server, seen by a WebSocket client speaking the Foxglove protocol."""

import json
import struct
import threading

import pytest

from mjexplore.episode import EpisodeConfig
from mjexplore.io.mcap_log import TOPICS
from mjexplore.scenes.canonical import resolve_scene

sync_client = pytest.importorskip("websockets.sync.client")
from mcap.reader import make_reader  # noqa: E402
from websockets.exceptions import ConnectionClosed  # noqa: E402

# foxglove-sdk speaks foxglove.sdk.v1; Foxglove's older name for the same protocol follows.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
TIMEOUT = 60.0  # Seconds for any one wait: connecting, a message, the episode's end.
MESSAGE_DATA, TIME = 0x01, 0x02  # Binary opcodes from the server.


def _watch_scans(url):
    """Connects as Foxglove does, subscribes to /scan once every topic is advertised and
    reads until the server closes: (channels by topic, [(log time, payload)], [time])."""
    advertised, data, times = {}, [], []
    with sync_client.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=TIMEOUT,
                             proxy=None) as ws:
        info = json.loads(ws.recv(timeout=TIMEOUT))
        assert info["op"] == "serverInfo" and "time" in info["capabilities"]
        while not set(TOPICS) <= set(advertised):
            message = json.loads(ws.recv(timeout=TIMEOUT))
            if message["op"] == "advertise":
                advertised.update({c["topic"]: c for c in message["channels"]})
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 7, "channelId": advertised["/scan"]["id"]}]}))
        try:
            while True:  # Until the server stops at the episode's end.
                frame = ws.recv(timeout=TIMEOUT)
                if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                    subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                    assert subscription == 7
                    data.append((log_time, frame[13:]))
                elif isinstance(frame, bytes) and frame[0] == TIME:
                    times.append(struct.unpack_from("<Q", frame, 1)[0])
        except ConnectionClosed:
            pass
    return advertised, data, times


def test_live_server_streams_the_mcap_topics_while_the_episode_runs(tmp_path):
    from mjexplore.eval.run import run_episode
    from mjexplore.io.live import LiveServer
    from mjexplore.render.replay import _decoders

    path = tmp_path / "ep.mcap"
    live = LiveServer("127.0.0.1", 0, wait=True)  # Port 0: a free one.
    outcome = {}

    def episode():
        try:
            outcome["result"] = run_episode(resolve_scene("train_loop"), "nearest", 0,
                                            EpisodeConfig(max_time=2.0), mcap_path=path,
                                            live=live)
        except BaseException as exc:  # noqa: BLE001 - reported by the test below
            outcome["error"] = exc
        finally:
            live.stop()

    runner = threading.Thread(target=episode, daemon=True)
    runner.start()
    assert live.url == f"ws://127.0.0.1:{live.port}" and live.port > 0
    try:
        advertised, data, times = _watch_scans(live.url)
    finally:  # Also if the client fails: the server stops, the episode ends.
        live.stop()
        runner.join(TIMEOUT)
    assert not runner.is_alive() and "error" not in outcome

    scan = advertised["/scan"]
    assert (scan["schemaName"], scan["encoding"]) == ("foxglove.LaserScan", "protobuf")
    with open(path, "rb") as f:
        reader = make_reader(f)
        classes = _decoders(reader.get_summary())
        recorded = [(m.log_time, m.data, classes[s.id])
                    for s, _, m in reader.iter_messages(topics=["/scan"])]
    # Held until the subscription, the stream has every scan from the first, as in the file.
    assert len(data) == len(recorded) == len(outcome["result"].ratio_curve) == 21
    assert [(t, d) for t, d, _ in recorded] == data
    first = recorded[0][2].FromString(data[0][1])
    assert first.frame_id == "base_scan" and len(first.ranges) == 360
    # The server's time (Foxglove's current time) is the simulated time of each scan.
    assert times == [t for t, _ in data]


def test_live_server_refuses_a_taken_port():
    from mjexplore.errors import UserInputError
    from mjexplore.io.live import LiveServer

    with LiveServer("127.0.0.1", 0) as first:
        with pytest.raises(UserInputError, match="free port"):
            LiveServer("127.0.0.1", first.port)


def test_live_only_builds_no_message_while_nobody_subscribes(monkeypatch):
    from mjexplore.eval.run import run_episode
    from mjexplore.io import mcap_log
    from mjexplore.io.live import LiveServer

    def refuse(*args, **kwargs):
        raise AssertionError("built a message that no sink takes")

    for name in ("FoxgloveLaserScan", "FrameTransforms", "PoseInFrame", "Grid", "SceneUpdate"):
        monkeypatch.setattr(mcap_log, name, refuse)
    with LiveServer("127.0.0.1", 0) as live:  # No client connects.
        result = run_episode(resolve_scene("train_loop"), "nearest", 0,
                             EpisodeConfig(max_time=1.0), live=live)
    assert result.metrics["decisions"] >= 1 and len(result.ratio_curve) == 11
