"""The viewer's wire format, both ways, and the checks on what the page sends.

Page → server: WebSocket text messages, JSON objects of at most `MAX_MESSAGE` bytes, with
numbers, booleans and the mode name only — never a path or code:

* ``{"t": "cam", "seq": n, "eye": [x, y, z], "yaw": deg, "pitch": deg}``: the camera moved
  (``seq`` increases; it comes back in the frame rendered for it);
* ``{"t": "opts", "mode": "shaded", "frustum": true, "cones": true, "occlusion": true,
  "cut": null or height, "hiz_level": k, "inset": true, "lossless": false}`` (any subset);
* ``{"t": "ack", "n": frame_number}``: a frame was displayed (flow control: at most
  `IN_FLIGHT` frames are unacknowledged, so a slow page never makes frames queue up).

Anything else — not JSON, too long, an unknown type or key, a wrong type, a non-finite or
out-of-range number, a binary message — is dropped and logged (`BadMessage`); the
connection stays open.

Server → page: a text ``{"t": "hello", ...}`` once the scene is loaded (name, size,
starting camera, speed, modes, scales), ``{"t": "error", "message": ...}`` if loading
failed, and one binary message per frame: a little-endian uint32 header length, the
header (UTF-8 JSON, `clraster.viewer.engine.Picture.header` plus ``n``, the frame number),
the main image and the pane image (their lengths are ``main_bytes`` / ``inset_bytes``).
"""

from __future__ import annotations

import json
import math
import struct
from typing import Any

from .engine import ViewState
from .pictures import MODES

__all__ = ["IN_FLIGHT", "MAX_MESSAGE", "BadMessage", "apply", "pack_frame", "parse",
           "unpack_frame"]

#: Largest page message accepted (bytes); the longest legal one is about 200.
MAX_MESSAGE = 1024
#: Frames sent and not yet acknowledged, at most.
IN_FLIGHT = 2
#: Largest |coordinate| of an eye (scene units): beyond float32's exact integers the
#: renderer's precision is gone anyway.
MAX_COORD = 1e7
_OPTS = {"mode": str, "frustum": bool, "cones": bool, "occlusion": bool, "cut": (float, None),
         "hiz_level": int, "inset": bool, "lossless": bool}


class BadMessage(ValueError):
    """A page message that is dropped: the text says why."""


def _number(v: Any, name: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise BadMessage(f"{name} must be a number, got {type(v).__name__}")
    f = float(v)
    if not (math.isfinite(f) and lo <= f <= hi):
        raise BadMessage(f"{name} must be finite and in [{lo}, {hi}], got {v!r}")
    return f


def parse(text: str | bytes) -> dict[str, Any]:
    """The checked message of one page message (see the module docstring); BadMessage
    otherwise."""
    if isinstance(text, bytes):
        raise BadMessage("binary messages are not accepted")
    if len(text) > MAX_MESSAGE:
        raise BadMessage(f"message of {len(text)} characters, over {MAX_MESSAGE}")
    try:
        msg = json.loads(text)
    except ValueError:
        raise BadMessage("not JSON") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("t"), str):
        raise BadMessage("not an object with a type 't'")
    kind = msg["t"]
    if kind == "cam":
        if set(msg) != {"t", "seq", "eye", "yaw", "pitch"}:
            raise BadMessage(f"cam needs exactly seq, eye, yaw, pitch; got {sorted(msg)}")
        eye = msg["eye"]
        if not isinstance(eye, list) or len(eye) != 3:
            raise BadMessage("eye must be a list of three numbers")
        return {"t": "cam", "seq": int(_number(msg["seq"], "seq", 0, 2**53)),
                "eye": [_number(v, "eye", -MAX_COORD, MAX_COORD) for v in eye],
                "yaw": _number(msg["yaw"], "yaw", -1e6, 1e6),
                "pitch": _number(msg["pitch"], "pitch", -90.0, 90.0)}
    if kind == "opts":
        out: dict[str, Any] = {"t": "opts"}
        for key, value in msg.items():
            if key == "t":
                continue
            if key not in _OPTS:
                raise BadMessage(f"unknown option {key!r}")
            if key == "mode":
                if value not in MODES:
                    raise BadMessage(f"mode must be one of {MODES}, got {value!r}")
                out[key] = value
            elif key == "cut":
                out[key] = None if value is None else _number(value, "cut", -MAX_COORD,
                                                              MAX_COORD)
            elif key == "hiz_level":
                out[key] = int(_number(value, "hiz_level", 0, 16))
            else:
                if not isinstance(value, bool):
                    raise BadMessage(f"{key} must be true or false, got {value!r}")
                out[key] = value
        return out
    if kind == "ack":
        if set(msg) != {"t", "n"}:
            raise BadMessage("ack needs exactly n")
        return {"t": "ack", "n": int(_number(msg["n"], "n", 0, 2**53))}
    raise BadMessage(f"unknown message type {kind!r}")


def apply(state: ViewState, msg: dict[str, Any]) -> ViewState:
    """`state` changed by a parsed "cam" or "opts" message."""
    from dataclasses import replace

    if msg["t"] == "cam":
        return replace(state, camera=state.camera.moved(msg["eye"], msg["yaw"], msg["pitch"]),
                       seq=msg["seq"])
    changes = {k: v for k, v in msg.items() if k != "t"}
    return replace(state, **changes)


def pack_frame(header: dict[str, Any], main: bytes, inset: bytes) -> bytes:
    """One binary frame message (see the module docstring)."""
    head = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(head)) + head + main + inset


def unpack_frame(data: bytes) -> tuple[dict[str, Any], bytes, bytes]:
    """(header, main image, pane image) of a binary frame message."""
    (n,) = struct.unpack_from("<I", data)
    header = json.loads(data[4:4 + n])
    a = 4 + n + header["main_bytes"]
    return header, data[4 + n:a], data[a:a + header["inset_bytes"]]
