"""The live view's examples never rot: the Foxglove layout names only topics and fields the live
view streams, the demo streams decodable messages to a spec-written client, and the HTML page
asks for the SDK's subprotocol and streamed topics."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from foxglove_ws_client import FoxgloveClient, protobuf_class

from cmm_comp.daemon.live import SCENE_TOPIC, STREAMED_TOPICS, SUBPROTOCOL
from cmm_comp.daemon.live.scene import FRAME_ID
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS, check_message

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "examples" / "foxglove-layout.json"
PAGE = ROOT / "examples" / "live-view.html"


def _paths(node: Any) -> list[str]:
    """Every message path in a layout's panel configs (``value`` / ``topicPath``)."""
    out: list[str] = []
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ("value", "topicPath") and isinstance(value, str):
                out.append(value)
            else:
                out += _paths(value)
    elif isinstance(node, list):
        for item in node:
            out += _paths(item)
    return out


def _leaves(tree: Any) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return _leaves(tree["first"]) + _leaves(tree["second"])


def test_the_layout_names_streamed_topics_and_fields() -> None:
    layout = json.loads(LAYOUT.read_text(encoding="utf-8"))
    panels = layout["configById"]
    assert sorted(_leaves(layout["layout"])) == sorted(panels)
    types = {pid.split("!")[0] for pid in panels}
    assert {"Plot", "3D", "Table"} <= types  # corrections plot, 3-D arrows, status table
    paths = _paths(panels)
    assert paths
    for path in paths:
        m = re.fullmatch(r"(/cmm/[a-z_]+)(\{(\w+)==\"[^\"]*\"\})?(?:\.(\w+))?", path)
        assert m, f"unexpected message path {path!r}"
        topic, _, filter_key, field = m.groups()
        assert topic in STREAMED_TOPICS, path
        props = TOPIC_SCHEMAS[topic].schema["properties"]
        for key in (filter_key, field):
            assert key is None or key in props, f"{path}: {key} is not a field of {topic}"
    three_d = panels["3D!scene"]
    assert three_d["followTf"] == FRAME_ID
    assert list(three_d["topics"]) == [SCENE_TOPIC]


def test_the_page_speaks_the_sdks_subprotocol_and_asks_for_streamed_topics() -> None:
    html = PAGE.read_text(encoding="utf-8")
    assert f'"{SUBPROTOCOL}"' in html
    wanted = re.search(r"const WANTED = \[(.*?)\];", html)
    assert wanted is not None
    topics = re.findall(r'"([^"]+)"', wanted.group(1))
    assert topics and set(topics) <= set(STREAMED_TOPICS)
    assert "getUint32(1, true)" in html and "new Uint8Array(buf, 13)" in html  # spec layout


def test_the_demo_streams_decodable_messages() -> None:
    demo = subprocess.Popen(
        [sys.executable, str(ROOT / "examples" / "live_demo.py"), "--port", "0",
         "--rate-hz", "200", "--seconds", "60"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    assert demo.stdout is not None
    try:
        line = demo.stdout.readline()
        assert line.startswith("streaming on ws://127.0.0.1:"), line
        topics = ["/cmm/raw", "/cmm/corrected", "/cmm/temperature", SCENE_TOPIC]
        with FoxgloveClient(line.split()[2], timeout_s=20.0) as client:
            client.wait_for_channels(topics)
            client.subscribe(topics)
            seen: dict[str, int] = {}
            while len(seen) < len(topics) or min(seen.values()) < 2:
                for m in client.receive(1):
                    seen[m.topic] = seen.get(m.topic, 0) + 1
                    if m.topic == SCENE_TOPIC:
                        update = protobuf_class(client.channels[SCENE_TOPIC]).FromString(m.payload)
                        assert update.entities and update.entities[0].frame_id == FRAME_ID
                    else:
                        check_message(m.topic, m.json())
        demo.send_signal(signal.SIGINT)
        out, err = demo.communicate(timeout=20)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.communicate()
    assert demo.returncode == 0, err
    assert re.search(r"sent \d+ messages, \d+ scene updates, dropped 0", out), out


@pytest.mark.parametrize("rate", ["nan", "-5"])
def test_the_demo_refuses_a_bad_rate(rate: str) -> None:
    run = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "live_demo.py"), "--rate-hz", rate],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 2 and "--rate-hz" in run.stderr and "Traceback" not in run.stderr
