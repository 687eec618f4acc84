"""CAN input: frames described by a DBC file (python-can + cantools), classic CAN or CAN FD.

One module per step of the way from a DBC to a tick:

* :mod:`~cablesvc.sources.can.dbc`: the cablesvc frame layouts (classic and FD), their ids,
  and :func:`make_dbc`, which writes them as DBC text (``robots/<robot>.dbc``,
  ``robots/<robot>-fd.dbc``);
* :mod:`~cablesvc.sources.can.codec`: DBC signals compiled into numpy plans
  (:class:`FrameCodec`: one message; ``TickCodec``: all frames of a tick), so frames are
  encoded and decoded without calling cantools per frame;
* :mod:`~cablesvc.sources.can.layout`: a DBC read and checked against the conventions
  (:func:`load_can_layout` -> :class:`CanLayout`) and :func:`encode_tick` (a tick's frames);
* :mod:`~cablesvc.sources.can.assembler`: :class:`TickAssembler`, frames in, complete
  ticks or rejections out (deadline, missing and late frames, clock steps);
* :mod:`~cablesvc.sources.can.bus`: :func:`open_bus` (python-can);
* :mod:`~cablesvc.sources.can.source`: :class:`CanSource` (``kind = "can"``) and
  :class:`CanSourceConfig`.

A bus that crosses processes without vcan (tests, benches, the simulated controller):
:func:`cablesvc.netutil.loopback_bus_config`.
"""

from __future__ import annotations

from cablesvc.sources.can.assembler import CLOCK_STEP_MARGIN_S, EVENT_REASONS, TickAssembler
from cablesvc.sources.can.bus import open_bus
from cablesvc.sources.can.codec import FrameCodec
from cablesvc.sources.can.dbc import (
    CABLE_BASE_ID,
    FD_FRAME_CABLES,
    FD_LENGTHS,
    FD_SYNC_CABLES,
    NOT_AVAILABLE,
    PLATFORM_FD_ID,
    PLATFORM_IDS,
    SYNC_ID,
    dbc_suffix,
    make_dbc,
)
from cablesvc.sources.can.layout import CanLayout, encode_tick, load_can_layout
from cablesvc.sources.can.source import CanSource, CanSourceConfig

__all__ = [
    "CABLE_BASE_ID",
    "CLOCK_STEP_MARGIN_S",
    "EVENT_REASONS",
    "FD_FRAME_CABLES",
    "FD_LENGTHS",
    "FD_SYNC_CABLES",
    "NOT_AVAILABLE",
    "PLATFORM_FD_ID",
    "PLATFORM_IDS",
    "SYNC_ID",
    "CanLayout",
    "CanSource",
    "CanSourceConfig",
    "FrameCodec",
    "TickAssembler",
    "dbc_suffix",
    "encode_tick",
    "load_can_layout",
    "make_dbc",
    "open_bus",
]
