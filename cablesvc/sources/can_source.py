"""CAN input: frames described by a DBC file (python-can + cantools), classic CAN or CAN FD.

Two layouts ship (``docs/sources.md`` has the tables), both written by :func:`make_dbc`:

**Classic** (``robots/ipanema3.dbc``, 8-byte frames, ``make_dbc(robot)``). Per tick:

* ``CABLE_<i>`` (id 0x100 + i), one per cable: ``motor_length_<i>`` int32 at 10 nm [m],
  ``force_<i>`` int24 at 1 mN [N] (raw -2**23 = ``not_available``: no force sensor),
  ``tick_counter`` uint8;
* ``PLATFORM_X/Y/Z`` (0x140-0x142): ``position_x/y/z`` int32 at 10 nm [m] (raw -2**31 =
  ``not_available``: no pose), ``PLATFORM_X`` also ``temperature`` int16 at 0.01 deg C
  (raw -2**15 = ``not_available``), each with ``tick_counter``;
* ``PLATFORM_QXY``/``PLATFORM_QZW`` (0x143, 0x144): ``orientation_qx..qw`` int28 at 1e-8
  (raw -2**27 = ``not_available``), ``tick_counter``;
* ``SYNC`` (0x150) last: ``t`` uint40 at 1 us [s] (12.7 days before it wraps) and ``seq``
  uint24 (the controller's tick counter; ``tick_counter`` = seq mod 256).

That is m + 6 frames per tick (14 for 8 cables): too many for 1 kHz on a 1 Mbit/s bus.

**CAN FD** (``robots/ipanema3-fd.dbc``, ``make_dbc(robot, fd=True)``; frames up to 64 bytes,
bit rate switch), same signals and resolutions. Per tick:

* ``PLATFORM`` (0x140, 32 bytes): ``tick_counter``, the seven pose signals and ``temperature``;
* ``SYNC`` (0x150, 64 bytes for up to 8 cables) last: ``t``, ``seq`` and the motor length and
  force of cables 0-7; more cables go in ``CABLES_<k>`` frames (0x100 + k, 9 cables each,
  with ``tick_counter``), sent before the SYNC.

So 2 frames per tick for up to 8 cables (1 without a pose).

:class:`TickAssembler` turns frames into ticks: frames are grouped by their rolling
``tick_counter``, so frames of different ticks never mix, and the SYNC frame closes the
tick (the SYNC may carry data signals itself). A tick is delivered only when every data
frame of the DBC arrived before its SYNC; otherwise, or when no SYNC comes within
``deadline_s`` of its first frame, the tick is rejected (``missing_frames``, naming the
missing messages). Nothing is ever filled in from an earlier tick. Unknown ids, frames of
the wrong length and classic/FD mismatches are ``bad_frame``.

The DBC is the single source of truth: it is loaded with cantools, and every start bit,
width, byte order, signedness, scale, offset, float type and ``not_available`` value is
taken from cantools' signal objects. They are compiled once into a plan (byte indices,
shifts, masks, sign bits, scales as numpy arrays, :class:`FrameCodec`), so encoding and
decoding never call cantools per frame: one numpy gather/scatter per tick. The tests prove
the plan equal to cantools' own ``decode_message``/``encode_message``.

Cross-process tests (vcan needs a kernel module): python-can's ``udp_multicast`` interface
on an IPv6 interface-local group (ff11::/16, :func:`loopback_bus_config`), which never
leaves the host; ``fd=True`` carries CAN FD frames.
"""

from __future__ import annotations

import errno
import math
import os
import re
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal, Mapping, Optional, Sequence, Union

import can
import cantools
import numpy as np
from cantools.database.can import Database as CanDatabase
from pydantic import BaseModel, ConfigDict, Field

from cablesvc.config.robot import Robot
from cablesvc.sources.base import (
    Rejection,
    SourceConfigError,
    ThreadedSource,
    TickInput,
    find_robot_companion,
)

__all__ = [
    "CABLE_BASE_ID",
    "FD_FRAME_CABLES",
    "FD_LENGTHS",
    "FD_SYNC_CABLES",
    "LOOPBACK_GROUP_IPV4",
    "LOOPBACK_GROUP_IPV6",
    "LOOPBACK_PORT",
    "NOT_AVAILABLE",
    "PLATFORM_FD_ID",
    "SYNC_ID",
    "CanLayout",
    "CanSource",
    "CanSourceConfig",
    "FrameCodec",
    "TickAssembler",
    "dbc_suffix",
    "encode_tick",
    "free_udp_port",
    "load_can_layout",
    "loopback_bus_config",
    "make_dbc",
    "open_bus",
]

#: Choice name (DBC ``VAL_``) that marks "this quantity is not measured" in a signal.
NOT_AVAILABLE = "not_available"
#: CAN id of ``CABLE_0``; cable i uses CABLE_BASE_ID + i (classic). CAN FD: ``CABLES_<k>``.
CABLE_BASE_ID = 0x100
#: CAN ids of the platform frames (classic layout).
PLATFORM_IDS = {"PLATFORM_X": 0x140, "PLATFORM_Y": 0x141, "PLATFORM_Z": 0x142,
                "PLATFORM_QXY": 0x143, "PLATFORM_QZW": 0x144}
#: CAN id of the FD layout's ``PLATFORM`` frame (pose and temperature).
PLATFORM_FD_ID = 0x140
#: CAN id of the SYNC frame that closes a tick.
SYNC_ID = 0x150
#: Data lengths a CAN FD frame can have (DLC 0-15).
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
#: CAN FD layout: cables carried by the SYNC frame (after t and seq), and by each CABLES_<k>.
FD_SYNC_CABLES = 8
FD_FRAME_CABLES = 9

#: IPv6 interface-local multicast group (scope 1: never sent on a wire) for cross-process buses.
LOOPBACK_GROUP_IPV6 = "ff11::c0:ab1e"
#: IPv4 fallback group, used with TTL 0 (the kernel loops it back and sends no data out).
LOOPBACK_GROUP_IPV4 = "239.255.42.99"
#: Default UDP port of :func:`loopback_bus_config`.
LOOPBACK_PORT = 43117
#: A frame time this much [s] (beyond the deadline) earlier than the newest frame time seen
#: means the clock was stepped back (NTP, an operator): :class:`TickAssembler` re-bases.
CLOCK_STEP_MARGIN_S = 0.1
#: Reasons :class:`TickAssembler` returns that are events (counted in ``events``), not rejections.
EVENT_REASONS = frozenset({"clock_step"})

_POSE_SIGNALS = ("position_x", "position_y", "position_z",
                 "orientation_qx", "orientation_qy", "orientation_qz", "orientation_qw")
_CABLE_RE = re.compile(r"^(motor_length|force)_(\d+)$")


def dbc_suffix(fd: bool) -> str:
    """The file-name suffix of a robot's default DBC: ``-fd.dbc`` for CAN FD, else ``.dbc``."""
    return "-fd.dbc" if fd else ".dbc"


# --------------------------------------------------------------------------------------
# DBC generation
# --------------------------------------------------------------------------------------


def _q(s: str) -> str:
    return s.replace("\\", "/").replace('"', "'")


def make_dbc(robot: Robot, fd: bool = False) -> str:
    """The DBC text of the cablesvc frame layout for ``robot``.

    ``fd=False``: classic CAN, one 8-byte CABLE frame per cable (``robots/ipanema3.dbc``).
    ``fd=True``: CAN FD, the whole tick in as few frames as possible
    (``robots/ipanema3-fd.dbc``; see the module docstring). Write your own file from it for
    another robot (or edit it: the assembler reads every position and scale from the DBC).
    """
    return _make_fd_dbc(robot) if fd else _make_classic_dbc(robot)


def _make_classic_dbc(robot: Robot) -> str:
    geom = robot.geometry()
    m = geom.n_cables
    if m > 0x40:
        raise ValueError(f"robot {robot.name}: {m} cables; this layout has ids for at most 64")
    bo: list[str] = []
    cm: list[str] = []
    val: list[str] = []

    def msg(can_id: int, name: str, comment: str, signals: list[tuple[str, str, str, str]]) -> None:
        lines = [f"BO_ {can_id} {name}: 8 CONTROLLER"]
        for sname, spec, unit, scomment in signals:
            lines.append(f' SG_ {sname} : {spec} "{unit}" CABLESVC')
            cm.append(f'CM_ SG_ {can_id} {sname} "{_q(scomment)}";')
        bo.append("\n".join(lines))
        cm.append(f'CM_ BO_ {can_id} "{_q(comment)}";')

    counter = ("tick_counter", "56|8@1+ (1,0) [0|255]", "",
               "rolling tick counter = SYNC.seq mod 256; all frames of one tick carry the same value")
    for i in range(m):
        cid = CABLE_BASE_ID + i
        msg(cid, f"CABLE_{i}",
            f"cable {i} ({geom.cable_names[i]}): winch motor length and measured force, once per tick",
            [(f"motor_length_{i}", "0|32@1- (1e-08,0) [-21.47483647|21.47483647]", "m",
              f"unstretched cable length paid out by winch {i}, m, resolution 10 nm"),
             (f"force_{i}", "32|24@1- (0.001,0) [-8388.607|8388.607]", "N",
              f"measured tension of cable {i}, N, resolution 1 mN; raw -8388608 = not_available "
              f"(no force sensor)"),
             counter])
        val.append(f'VAL_ {cid} force_{i} -8388608 "{NOT_AVAILABLE}" ;')
    pos = "0|32@1- (1e-08,0) [-21.47483647|21.47483647]"
    for axis in "xyz":
        name = f"PLATFORM_{axis.upper()}"
        sigs = [(f"position_{axis}", pos, "m",
                 f"platform reference point {axis}, world frame, m, resolution 10 nm; "
                 f"raw -2147483648 = not_available (no pose this tick)")]
        if axis == "x":
            sigs.append(("temperature", "32|16@1- (0.01,0) [-327.67|327.67]", "degC",
                         "ambient / cable temperature, deg C, resolution 0.01; raw -32768 = not_available"))
        sigs.append(counter)
        msg(PLATFORM_IDS[name], name, f"platform position {axis}"
            + (" and temperature" if axis == "x" else ""), sigs)
        val.append(f'VAL_ {PLATFORM_IDS[name]} position_{axis} -2147483648 "{NOT_AVAILABLE}" ;')
        if axis == "x":
            val.append(f'VAL_ {PLATFORM_IDS[name]} temperature -32768 "{NOT_AVAILABLE}" ;')
    quat = "{}|28@1- (1e-08,0) [-1.34217727|1.34217727]"
    for name, (a, b) in (("PLATFORM_QXY", ("qx", "qy")), ("PLATFORM_QZW", ("qz", "qw"))):
        cid = PLATFORM_IDS[name]
        msg(cid, name, f"platform orientation, unit quaternion components {a}, {b}",
            [(f"orientation_{a}", quat.format(0), "",
              f"orientation quaternion {a} (world from platform), resolution 1e-8; "
              f"raw -134217728 = not_available"),
             (f"orientation_{b}", quat.format(28), "",
              f"orientation quaternion {b}, resolution 1e-8; raw -134217728 = not_available"),
             counter])
        val.append(f'VAL_ {cid} orientation_{a} -134217728 "{NOT_AVAILABLE}" ;')
        val.append(f'VAL_ {cid} orientation_{b} -134217728 "{NOT_AVAILABLE}" ;')
    msg(SYNC_ID, "SYNC",
        "closes the tick: sent after all other frames of the tick; the tick is complete when "
        "every frame with tick_counter = seq mod 256 has arrived",
        [("t", "0|40@1+ (1e-06,0) [0|1099511.627775]", "s",
          "controller clock at this tick, s, resolution 1 us; wraps after 12.7 days"),
         ("seq", "40|24@1+ (1,0) [0|16777215]", "",
          "controller tick counter, +1 per tick, wraps after 2^24 ticks (4.66 h at 1 kHz; "
          "cablesvc follows the wrap)")])
    head = [
        'VERSION "cablesvc-1"',
        "",
        "NS_ :",
        "\tCM_",
        "\tVAL_",
        "",
        "BS_:",
        "",
        "BU_: CONTROLLER CABLESVC",
        "",
    ]
    file_comment = (
        f"cablesvc CAN layout for robot {robot.name} ({m} cables). Classic CAN, 8-byte frames, "
        f"11-bit ids, little-endian (Intel) signals. Per tick: CABLE_0..CABLE_{m - 1}, PLATFORM_X, "
        f"PLATFORM_Y, PLATFORM_Z, PLATFORM_QXY, PLATFORM_QZW, then SYNC ({m + 6} frames). "
        f"Every data frame carries tick_counter = SYNC.seq mod 256. SI units. Generated by "
        f"cablesvc.sources.can_source.make_dbc; see docs/sources.md"
    )
    body = "\n\n".join(bo)
    comments = [f'CM_ "{_q(file_comment)}";', 'CM_ BU_ CONTROLLER "the robot controller (sender)";',
                'CM_ BU_ CABLESVC "cablesvc (receiver, never transmits)";'] + cm
    return "\n".join(head) + "\n" + body + "\n\n" + "\n".join(comments) + "\n" + "\n".join(val) + "\n"


def _fd_length(nbytes: int) -> int:
    """The smallest CAN FD data length that holds ``nbytes`` bytes."""
    for n in FD_LENGTHS:
        if n >= nbytes:
            return n
    raise ValueError(f"{nbytes} bytes do not fit a CAN FD frame (at most 64)")


def _make_fd_dbc(robot: Robot) -> str:
    geom = robot.geometry()
    m = geom.n_cables
    if m > FD_SYNC_CABLES + FD_FRAME_CABLES * 0x40:
        raise ValueError(f"robot {robot.name}: {m} cables; too many for this layout")
    ml_spec = "{}|32@1- (1e-08,0) [-21.47483647|21.47483647]"
    force_spec = "{}|24@1- (0.001,0) [-8388.607|8388.607]"
    bo: list[str] = []
    cm: list[str] = []
    val: list[str] = []
    ids: list[int] = []

    def msg(can_id: int, name: str, nbits: int, comment: str, signals: list[tuple[str, str, str, str]]) -> None:
        length = _fd_length((nbits + 7) // 8)
        lines = [f"BO_ {can_id} {name}: {length} CONTROLLER"]
        for sname, spec, unit, scomment in signals:
            lines.append(f' SG_ {sname} : {spec} "{unit}" CABLESVC')
            cm.append(f'CM_ SG_ {can_id} {sname} "{_q(scomment)}";')
        bo.append("\n".join(lines))
        cm.append(f'CM_ BO_ {can_id} "{_q(comment)}";')
        ids.append(can_id)

    def cable_signals(cables: Sequence[int], first_bit: int, cid: int) -> list[tuple[str, str, str, str]]:
        n = len(cables)
        sigs = []
        for j, i in enumerate(cables):
            sigs.append((f"motor_length_{i}", ml_spec.format(first_bit + 32 * j), "m",
                         f"unstretched cable length paid out by winch {i} ({geom.cable_names[i]}), m, "
                         f"resolution 10 nm"))
        for j, i in enumerate(cables):
            sigs.append((f"force_{i}", force_spec.format(first_bit + 32 * n + 24 * j), "N",
                         f"measured tension of cable {i} ({geom.cable_names[i]}), N, resolution 1 mN; "
                         f"raw -8388608 = not_available (no force sensor)"))
            val.append(f'VAL_ {cid} force_{i} -8388608 "{NOT_AVAILABLE}" ;')
        return sigs

    counter = ("tick_counter", "0|8@1+ (1,0) [0|255]", "",
               "rolling tick counter = SYNC.seq mod 256; all frames of one tick carry the same value")
    in_sync = list(range(min(m, FD_SYNC_CABLES)))
    rest = list(range(len(in_sync), m))
    chunks = [rest[k:k + FD_FRAME_CABLES] for k in range(0, len(rest), FD_FRAME_CABLES)]
    for k, cables in enumerate(chunks):
        cid = CABLE_BASE_ID + k
        msg(cid, f"CABLES_{k}", 8 + 56 * len(cables),
            f"cables {cables[0]}-{cables[-1]}: winch motor lengths and measured forces, once per tick",
            [counter] + cable_signals(cables, 8, cid))
    pose = [
        ("position_x", "8|32@1- (1e-08,0) [-21.47483647|21.47483647]", "m",
         "platform reference point x, world frame, m, resolution 10 nm; raw -2147483648 = not_available "
         "(no pose this tick)"),
        ("position_y", "40|32@1- (1e-08,0) [-21.47483647|21.47483647]", "m",
         "platform reference point y, m, resolution 10 nm; raw -2147483648 = not_available"),
        ("position_z", "72|32@1- (1e-08,0) [-21.47483647|21.47483647]", "m",
         "platform reference point z, m, resolution 10 nm; raw -2147483648 = not_available"),
    ]
    for c, start in (("qx", 104), ("qy", 132), ("qz", 160), ("qw", 188)):
        pose.append((f"orientation_{c}", f"{start}|28@1- (1e-08,0) [-1.34217727|1.34217727]", "",
                     f"orientation quaternion {c} (world from platform), resolution 1e-8; "
                     f"raw -134217728 = not_available"))
    temp = ("temperature", "216|16@1- (0.01,0) [-327.67|327.67]", "degC",
            "ambient / cable temperature, deg C, resolution 0.01; raw -32768 = not_available")
    msg(PLATFORM_FD_ID, "PLATFORM", 232, "platform pose (position, orientation quaternion) and temperature",
        [counter] + pose + [temp])
    for name, spec, _u, _c in pose:
        na = -2147483648 if name.startswith("position") else -134217728
        val.append(f'VAL_ {PLATFORM_FD_ID} {name} {na} "{NOT_AVAILABLE}" ;')
    val.append(f'VAL_ {PLATFORM_FD_ID} temperature -32768 "{NOT_AVAILABLE}" ;')
    sync_sigs = [
        ("t", "0|40@1+ (1e-06,0) [0|1099511.627775]", "s",
         "controller clock at this tick, s, resolution 1 us; wraps after 12.7 days"),
        ("seq", "40|24@1+ (1,0) [0|16777215]", "",
         "controller tick counter, +1 per tick, wraps after 2^24 ticks (4.66 h at 1 kHz; "
         "cablesvc follows the wrap)"),
    ] + cable_signals(in_sync, 64, SYNC_ID)
    msg(SYNC_ID, "SYNC", 64 + 56 * len(in_sync),
        f"closes the tick: sent after all other frames of the tick; carries t, seq and cables "
        f"{in_sync[0]}-{in_sync[-1]}; the tick is complete when every frame with tick_counter = seq mod 256 "
        f"has arrived", sync_sigs)
    order = [f"CABLES_{k}" for k in range(len(chunks))] + ["PLATFORM", "SYNC"]
    head = [
        'VERSION "cablesvc-fd-1"',
        "",
        "NS_ :",
        "\tCM_",
        "\tBA_DEF_",
        "\tBA_",
        "\tVAL_",
        "\tBA_DEF_DEF_",
        "",
        "BS_:",
        "",
        "BU_: CONTROLLER CABLESVC",
        "",
    ]
    file_comment = (
        f"cablesvc CAN FD layout for robot {robot.name} ({m} cables). CAN FD frames of up to 64 bytes with "
        f"bit rate switch, 11-bit ids, little-endian (Intel) signals; same resolutions as the classic "
        f"layout. Per tick: {', '.join(order[:-1])}, then SYNC ({len(order)} frames). Every data frame "
        f"carries tick_counter = SYNC.seq mod 256. SI units. Generated by "
        f"cablesvc.sources.can_source.make_dbc(robot, fd=True); see docs/sources.md"
    )
    attrs = [
        'BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","J1939PG","reserved",'
        '"reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved",'
        '"reserved","StandardCAN_FD","ExtendedCAN_FD";',
        'BA_DEF_ BO_ "CANFD_BRS" ENUM "0","1";',
        'BA_DEF_ "BusType" STRING ;',
        'BA_DEF_DEF_ "VFrameFormat" "StandardCAN";',
        'BA_DEF_DEF_ "CANFD_BRS" "1";',
        'BA_DEF_DEF_ "BusType" "";',
        'BA_ "BusType" "CAN FD";',
    ] + [f'BA_ "VFrameFormat" BO_ {cid} 14;' for cid in ids]
    body = "\n\n".join(bo)
    comments = [f'CM_ "{_q(file_comment)}";', 'CM_ BU_ CONTROLLER "the robot controller (sender)";',
                'CM_ BU_ CABLESVC "cablesvc (receiver, never transmits)";'] + cm
    return ("\n".join(head) + "\n" + body + "\n\n" + "\n".join(comments) + "\n" + "\n".join(attrs) + "\n"
            + "\n".join(val) + "\n")


# --------------------------------------------------------------------------------------
# compiled layout: the plan
# --------------------------------------------------------------------------------------

_I64 = np.dtype("<i8")  # frame bytes are read and written as little-endian 64-bit words
_I64_MIN = -(1 << 63)
_F32_MAX = float(np.finfo(np.float32).max)
_F64_MAX = float(np.finfo(np.float64).max)
_BELOW_2_63 = float(np.nextafter(2.0 ** 63, 0.0))


@dataclass(frozen=True)
class _Signal:
    """One DBC signal as cantools describes it (what the compiled plan needs)."""

    name: str
    start: int  # cantools' start bit (DBC numbering; big-endian: the most significant bit)
    length: int
    signed: bool
    scale: float
    offset: float
    little_endian: bool
    not_available: Optional[int]  # raw value meaning "not measured", or None (floats: NaN)
    is_float: bool = False

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    def span(self) -> tuple[int, int, int]:
        """(first byte, number of bytes, right shift): the bytes holding the signal, read as
        one integer (little-endian signals: least significant byte first; big-endian: most
        significant first), hold the raw value at bit ``shift``."""
        if self.little_endian:
            first, shift = divmod(self.start, 8)
            return first, (shift + self.length + 7) // 8, shift
        msb = (self.start // 8) * 8 + (7 - self.start % 8)  # bit index counted MSB-first
        lsb = msb + self.length - 1
        return msb // 8, lsb // 8 - msb // 8 + 1, 7 - lsb % 8


class _BitPlan:
    """Signals at fixed bit positions of a byte buffer (one frame, or the frames of a tick
    one after the other), compiled into numpy arrays.

    Decoding is one gather: for signal k, the (up to 8) bytes of its span are picked into
    place k of an (n, 8) byte matrix (in little-endian order: big-endian spans reversed,
    unused places from a zero pad byte) that is viewed as n int64 words; shifting the field
    to the top and arithmetic-shifting it down sign-extends it (unsigned fields are masked
    after); physical = raw * scale + offset, exactly as cantools computes it. Encoding
    reverses it: raw = (value - offset) / scale rounded half to even (cantools' ``round``),
    masked and shifted words, their bytes scattered back with one ``bincount`` (signals
    never share a bit, so adding the bytes is OR-ing them).
    """

    def __init__(self, placed: Sequence[tuple[_Signal, int]], length: int):
        n = len(placed)
        self.n = n
        self.length = int(length)
        self.signals = [s for s, _ in placed]
        idx = np.full((n, 8), self.length, dtype=np.intp)
        self.shift = np.zeros(n, np.int64)  # where the raw value starts in the gathered word
        self.lsh = np.zeros(n, np.int64)  # decode: field to the top ...
        self.rsh = np.zeros(n, np.int64)  # ... and down again, sign-extending
        self.umask = np.full(n, -1, np.int64)  # decode: unsigned fields masked after
        self.mask = np.zeros(n, np.int64)  # encode: the field's bits
        self.scale = np.ones(n)
        self.offset = np.zeros(n)
        self.lo = np.zeros(n)  # raw range that encodes a value (the not_available raw excluded)
        self.hi = np.zeros(n)
        self.na = np.full(n, _I64_MIN, np.int64)  # the not_available raw (none: a value no field < 64 bits has)
        self.has_na = np.zeros(n, dtype=bool)
        self.na_raw = np.zeros(n)
        f32: list[int] = []
        f64: list[int] = []
        full_width = False
        for k, (s, off) in enumerate(placed):
            first, nbytes, shift = s.span()
            if nbytes > 8:
                raise ValueError(f"signal {s.name}: {s.length} bits from bit {s.start} span {nbytes} bytes; "
                                 f"cablesvc handles signals within 8 consecutive bytes")
            if off + first + nbytes > self.length:
                raise ValueError(f"signal {s.name} does not fit in {self.length} bytes")
            pos = np.arange(nbytes)
            idx[k, :nbytes] = off + first + (pos if s.little_endian else pos[::-1])
            field_mask = (1 << s.length) - 1
            self.shift[k] = shift
            self.lsh[k] = 64 - shift - s.length
            self.rsh[k] = 64 - s.length
            self.mask[k] = _as_i64(field_mask)
            if not s.signed or s.is_float:
                self.umask[k] = _as_i64(field_mask)
            self.scale[k] = s.scale
            self.offset[k] = s.offset
            if s.is_float:
                (f32 if s.length == 32 else f64).append(k)
                self.has_na[k] = True  # NaN
                self.na_raw[k] = math.nan
                lim = _F32_MAX if s.length == 32 else _F64_MAX
                self.lo[k], self.hi[k] = -lim, lim
                continue
            if s.length == 64 and not s.signed:
                raise ValueError(f"signal {s.name}: unsigned 64-bit integers are not supported")
            full_width |= s.length == 64
            lo, hi = s.raw_min, s.raw_max
            if s.not_available is not None:
                self.has_na[k] = True
                self.na_raw[k] = s.not_available
                self.na[k] = s.not_available
                if s.not_available == lo:
                    lo += 1
                elif s.not_available == hi:
                    hi -= 1
            self.lo[k], self.hi[k] = float(lo), min(float(hi), _BELOW_2_63)
        self.idx = idx.ravel()
        self.f32 = np.array(f32, dtype=np.intp)
        self.f64 = np.array(f64, dtype=np.intp)
        self.floats = np.array(sorted(f32 + f64), dtype=np.intp)
        self.any_offset = bool(np.any(self.offset != 0.0))
        self._na_needs_mask = full_width  # a 64-bit field can hold the "no sentinel" value

    # ---------------------------------------------------------------- decode
    def words(self, buf: Union[bytes, bytearray]) -> np.ndarray:
        """Raw value of every signal (int64; sign-extended; float signals: their IEEE bits)
        from ``buf``: ``length`` bytes and one zero byte after them."""
        x = np.frombuffer(buf, np.uint8)[self.idx].view(_I64)
        x <<= self.lsh
        x >>= self.rsh
        x &= self.umask
        return x

    def phys(self, x: np.ndarray) -> np.ndarray:
        """Physical values (float64): raw * scale + offset, floats from their IEEE bits."""
        v = x.astype(np.float64)
        v *= self.scale
        if self.any_offset:
            v += self.offset
        if self.floats.size:
            with np.errstate(all="ignore"):  # NaN/inf bit patterns and overflow: as IEEE (and cantools) say
                if self.f32.size:
                    k = self.f32
                    v[k] = x[k].astype(np.uint32).view(np.float32) * self.scale[k] + self.offset[k]
                if self.f64.size:
                    k = self.f64
                    v[k] = x[k].view(np.float64) * self.scale[k] + self.offset[k]
        return v

    def not_available(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Which signals hold their not_available raw value (float signals: NaN)."""
        na = x == self.na
        if self._na_needs_mask:
            na &= self.has_na
        if self.floats.size:
            na[self.floats] = np.isnan(v[self.floats])
        return na

    # ---------------------------------------------------------------- encode
    def raw(self, vals: np.ndarray) -> np.ndarray:
        """Physical values -> raw values as floats: (value - offset) / scale, rounded half to
        even for integer signals (cantools' ``round``). NaN stays NaN."""
        r = (vals - self.offset) / self.scale if self.any_offset else vals / self.scale
        if self.floats.size:
            keep = r[..., self.floats].copy()
            np.rint(r, out=r)
            r[..., self.floats] = keep
        else:
            np.rint(r, out=r)
        return r

    def scatter(self, x: np.ndarray) -> np.ndarray:
        """Masked, shifted words (n,) or (rows, n) int64 -> the buffer bytes (length,) or
        (rows, length) uint8."""
        b = x.astype(_I64, copy=False).view(np.uint8)
        if x.ndim == 1:
            return np.bincount(self.idx, weights=b, minlength=self.length + 1)[: self.length].astype(np.uint8)
        rows, width = x.shape[0], self.length + 1
        flat = (self.idx[None, :] + width * np.arange(rows, dtype=np.intp)[:, None]).ravel()
        out = np.bincount(flat, weights=b.ravel(), minlength=rows * width).reshape(rows, width)
        return out[:, : self.length].astype(np.uint8)

    def pack(self, vals: np.ndarray, what: str) -> np.ndarray:
        """Physical values (n,) or (rows, n), NaN = not_available -> buffer bytes.

        Raises ValueError naming ``what`` and the signal when a value cannot be sent.
        """
        r = self.raw(vals)
        if np.count_nonzero((r >= self.lo) & (r <= self.hi)) != r.size:  # NaN fails both
            r = self._not_ok(vals, r, what)
        if self.floats.size:
            ri = r.copy()
            ri[..., self.floats] = 0.0
            x = ri.astype(np.int64)
            if self.f32.size:
                x[..., self.f32] = r[..., self.f32].astype(np.float32).view(np.uint32)
            if self.f64.size:
                x[..., self.f64] = r[..., self.f64].view(np.int64)
        else:
            x = r.astype(np.int64)
        x &= self.mask
        x <<= self.shift
        return self.scatter(x)

    def _not_ok(self, vals: np.ndarray, r: np.ndarray, what: str) -> np.ndarray:
        nan = np.isnan(r)
        bad = nan & ~self.has_na
        if bad.any():
            at = tuple(np.argwhere(bad)[0])
            s = self.signals[at[-1]]
            raise ValueError(f"{what}{_row(at)}: signal {s.name} has no {NOT_AVAILABLE} value; "
                             f"cannot send a missing value")
        r = np.where(nan, self.na_raw, r)
        bad = ~nan & ~((r >= self.lo) & (r <= self.hi))
        if bad.any():
            at = tuple(np.argwhere(bad)[0])
            k = at[-1]
            s, v = self.signals[k], float(vals[at])
            if not math.isfinite(v):
                raise ValueError(f"{what}{_row(at)}: signal {s.name}: value {v!r} is not finite")
            lo, hi = self.lo[k] * s.scale + s.offset, self.hi[k] * s.scale + s.offset
            raise ValueError(f"{what}{_row(at)}: signal {s.name}: {v!r} is outside the range "
                             f"[{lo:g}, {hi:g}] of the DBC")
        return r


def _as_i64(v: int) -> int:
    """An unsigned 64-bit pattern as the int64 with the same bits."""
    return v - (1 << 64) if v >= 1 << 63 else v


def _row(at: tuple[int, ...]) -> str:
    return f" (row {at[0]})" if len(at) > 1 else ""


class FrameCodec:
    """One DBC message (a cantools ``Message``) compiled into a plan: its bytes <-> its
    signals without calling cantools.

    :meth:`decode` gives what ``db.decode_message(id, data, decode_choices=False)`` gives
    (physical values), :meth:`encode` what ``db.encode_message(id, values)`` gives (bytes;
    a None/NaN value is sent as the signal's ``not_available`` raw value), and
    :meth:`decode_raw` / :meth:`encode_raw` work on raw integers (float signals: the float).
    """

    def __init__(self, msg: Any, signals: Optional[list[_Signal]] = None):
        self.msg = msg
        self.name: str = msg.name
        self.frame_id: int = msg.frame_id
        self.is_extended: bool = bool(msg.is_extended_frame)
        self.is_fd: bool = bool(getattr(msg, "is_fd", False))
        self.length: int = int(msg.length)
        self.bitrate_switch: bool = self.is_fd and _brs(msg)
        if signals is None:
            signals = [_signal_of(s, msg.name, None) for s in msg.signals]
        self.signals = signals
        self.index = {s.name: k for k, s in enumerate(signals)}
        self.plan = _BitPlan([(s, 0) for s in signals], self.length)

    def _words(self, data: Union[bytes, bytearray]) -> np.ndarray:
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} data bytes, the DBC says {self.length}")
        return self.plan.words(bytes(data) + b"\0")

    def decode(self, data: Union[bytes, bytearray]) -> dict[str, float]:
        """Physical value of every signal (not_available raws decode like any other value)."""
        v = self.plan.phys(self._words(data))
        return dict(zip(self.index, v.tolist()))

    def decode_raw(self, data: Union[bytes, bytearray]) -> tuple[Union[int, float], ...]:
        """Raw value of every signal, in DBC order (integers; float signals: the float)."""
        w = self._words(data)
        raws: list[Any] = w.tolist()
        for k in self.plan.floats.tolist():
            fmt, n = ("<f", 4) if self.signals[k].length == 32 else ("<d", 8)
            raws[k] = struct.unpack(fmt, (int(w[k]) & ((1 << 8 * n) - 1)).to_bytes(n, "little"))[0]
        return tuple(raws)

    def encode(self, values: Mapping[str, Optional[float]]) -> bytes:
        """Frame bytes from physical values (every signal; None/NaN = not_available)."""
        vals = np.array([math.nan if values[s.name] is None else float(values[s.name]) for s in self.signals],
                        dtype=np.float64)
        return self.plan.pack(vals, self.name).tobytes()

    def encode_raw(self, raws: Sequence[Union[int, float]]) -> bytes:
        """Frame bytes from raw values in DBC order (integers; float signals: the float)."""
        raws = list(raws)
        if len(raws) != len(self.signals):
            raise ValueError(f"{self.name}: {len(raws)} raw values for {len(self.signals)} signals")
        u = np.zeros(len(raws), np.int64)
        for k, (s, v) in enumerate(zip(self.signals, raws)):
            if s.is_float:
                fmt = "<f" if s.length == 32 else "<d"
                u[k] = _as_i64(int.from_bytes(struct.pack(fmt, float(v)), "little"))
            else:
                u[k] = _as_i64(int(v) & ((1 << s.length) - 1))
        u <<= self.plan.shift
        return self.plan.scatter(u).tobytes()


def _brs(msg: Any) -> bool:
    """The message's CANFD_BRS attribute (bit rate switch), default on."""
    spec = getattr(msg, "dbc", None)
    if spec is None:
        return True
    definition = (spec.attribute_definitions or {}).get("CANFD_BRS")
    attr = (spec.attributes or {}).get("CANFD_BRS")
    value: Any = attr.value if attr is not None else (definition.default_value if definition is not None else 1)
    choices = definition.choices if definition is not None else None
    if choices and isinstance(value, int) and 0 <= value < len(choices):
        value = choices[value]
    return str(value).strip() != "0"


def _signal_of(sig: Any, where: str, problems: Optional[list[str]]) -> _Signal:
    na = None
    choices = getattr(sig, "choices", None) or {}
    for raw, label in choices.items():
        if str(label) == NOT_AVAILABLE:
            na = int(raw)
    if problems is not None and (getattr(sig, "is_multiplexer", False) or getattr(sig, "multiplexer_ids", None)):
        problems.append(f"{where}: signal {sig.name} is multiplexed; not supported")
    return _Signal(
        name=sig.name, start=int(sig.start), length=int(sig.length), signed=bool(sig.is_signed),
        scale=float(sig.scale), offset=float(sig.offset),
        little_endian=sig.byte_order == "little_endian", not_available=None if sig.is_float else na,
        is_float=bool(sig.is_float),
    )


#: kept for code that used the earlier name
_MessageCodec = FrameCodec


@dataclass
class CanLayout:
    """A DBC checked against the cablesvc conventions (see the module docstring).

    ``n_cables``; ``sync``: the SYNC codec; ``data``: the data-frame codecs in sending
    order (every one of them must arrive for a tick to complete); ``counter_bits``,
    ``seq_bits``; ``has_force``/``has_pose``/``has_temperature``: which quantities the DBC
    carries; ``fd``: some message is a CAN FD frame (the bus must be opened with fd=True).
    """

    path: str
    db: CanDatabase
    n_cables: int
    sync: FrameCodec
    data: list[FrameCodec]
    counter_bits: int
    seq_bits: int
    has_force: bool
    has_pose: bool
    has_temperature: bool
    by_id: dict[tuple[int, bool], FrameCodec] = field(default_factory=dict)
    #: signal name -> (message codec, index in its signals)
    where: dict[str, tuple[FrameCodec, int]] = field(default_factory=dict)
    fd: bool = False
    #: the whole tick compiled into one plan (set by :func:`load_can_layout`)
    tick: Any = field(default=None, repr=False)

    @property
    def data_names(self) -> list[str]:
        return [c.name for c in self.data]

    @property
    def frames(self) -> list[FrameCodec]:
        """Every message of a tick in sending order (data frames, then SYNC)."""
        return [*self.data, self.sync]

    @property
    def frames_per_tick(self) -> int:
        return len(self.data) + 1

    @property
    def bytes_per_tick(self) -> int:
        """Data bytes per tick (sum of the DLC lengths)."""
        return sum(c.length for c in self.frames)

    def signal(self, name: str) -> _Signal:
        codec, k = self.where[name]
        return codec.signals[k]


# a layout compiled from a cantools Database object is kept on that object (it lives as
# long as the database), so encode_tick(db, ...) compiles once per database
_CACHE_ATTR = "_cablesvc_layouts"
_DATA_NAMES_HELP = ("motor_length_<i>, force_<i>, position_x/y/z, orientation_qx/qy/qz/qw, temperature, "
                    "tick_counter")


def load_can_layout(dbc: Union[str, os.PathLike[str], CanDatabase], n_cables: Optional[int] = None) -> CanLayout:
    """Read (or take) a DBC and check it against the cablesvc conventions.

    ``n_cables``: the robot's cable count (None: taken from the DBC). Every problem found is
    raised at once as :class:`SourceConfigError` naming the file, message and signal.
    """
    if isinstance(dbc, CanDatabase):
        db, path = dbc, "<database>"
        cached = getattr(db, _CACHE_ATTR, {}).get(-1 if n_cables is None else n_cables)
        if cached is not None:
            return cached
    else:
        path = os.fspath(dbc)
        if not Path(path).is_file():
            raise SourceConfigError(f"{path}: DBC file not found")
        try:
            db = cantools.database.load_file(path, database_format="dbc", strict=True)
        except Exception as exc:  # cantools raises several parser error types
            raise SourceConfigError(f"{path}: not a readable DBC file: {exc}") from None
    problems: list[str] = []
    sync: Optional[FrameCodec] = None
    data: list[FrameCodec] = []
    where: dict[str, tuple[FrameCodec, int]] = {}
    counter_bits: set[int] = set()
    cables: dict[str, set[int]] = {"motor_length": set(), "force": set()}
    any_fd = False
    for msg in db.messages:
        mwhere = f"{path}: message {msg.name} (0x{msg.frame_id:X})"
        if msg.is_fd:
            any_fd = True
            if msg.length not in FD_LENGTHS:
                problems.append(f"{mwhere}: {msg.length} bytes is not a CAN FD frame length "
                                f"({', '.join(map(str, FD_LENGTHS))})")
        elif msg.length > 8:
            problems.append(f"{mwhere}: {msg.length} bytes in a classic CAN frame (at most 8; a longer frame "
                            f"must be a CAN FD frame: VFrameFormat StandardCAN_FD)")
        sigs = [_signal_of(s, mwhere, problems) for s in msg.signals]
        try:
            codec = FrameCodec(msg, sigs)
        except ValueError as exc:
            problems.append(f"{mwhere}: {exc}")
            continue
        names = {s.name for s in sigs}
        is_sync = "seq" in names or "t" in names
        if is_sync:
            if sync is not None:
                problems.append(f"{mwhere}: a second SYNC message (signals seq, t); {sync.name} is the first")
            if not {"seq", "t"} <= names:
                problems.append(f"{mwhere}: the SYNC message needs both signals seq and t")
            if "tick_counter" in names:
                problems.append(f"{mwhere}: the SYNC message carries seq; it has no tick_counter")
            sync = codec
        else:
            if "tick_counter" not in names:
                problems.append(f"{mwhere}: data frame without a tick_counter signal")
            data.append(codec)
        for k, s in enumerate(sigs):
            if s.name == "tick_counter":
                counter_bits.add(s.length)
                if s.signed or s.is_float or s.scale != 1 or s.offset != 0:
                    problems.append(f"{mwhere}: tick_counter must be an unsigned integer with scale 1, offset 0")
                continue
            if is_sync and s.name in ("seq", "t"):
                where[s.name] = (codec, k)
                continue
            mt = _CABLE_RE.match(s.name)
            if mt:
                cables[mt.group(1)].add(int(mt.group(2)))
            elif s.name not in _POSE_SIGNALS and s.name != "temperature":
                problems.append(f"{mwhere}: unknown signal {s.name!r} (known: {_DATA_NAMES_HELP}"
                                f"{'; and seq, t in the SYNC' if is_sync else ''})")
                continue
            if s.name in where:
                problems.append(f"{mwhere}: signal {s.name} also in message {where[s.name][0].name}")
            where[s.name] = (codec, k)
    if sync is None:
        problems.append(f"{path}: no SYNC message (a message with signals seq and t)")
    if len(counter_bits) > 1:
        problems.append(f"{path}: tick_counter has different widths {sorted(counter_bits)}; use one width")
    cbits = min(counter_bits) if counter_bits else 8
    seq_bits = 0
    if sync is not None and "seq" in sync.index:
        s = sync.signals[sync.index["seq"]]
        seq_bits = s.length
        if s.signed or s.is_float or s.scale != 1 or s.offset != 0:
            problems.append(f"{path}: SYNC.seq must be an unsigned integer with scale 1, offset 0")
        if seq_bits < cbits:
            problems.append(f"{path}: SYNC.seq has {seq_bits} bits, fewer than tick_counter ({cbits})")
        if seq_bits > 53:
            problems.append(f"{path}: SYNC.seq has {seq_bits} bits; at most 53 are supported")
    ml = cables["motor_length"]
    m = n_cables if n_cables is not None else len(ml)
    if ml != set(range(m)):
        problems.append(
            f"{path}: motor_length signals for cables {sorted(ml)}; the robot has {m} cables "
            f"(motor_length_0..motor_length_{m - 1} needed)"
        )
    fs = cables["force"]
    if fs and fs != set(range(m)):
        problems.append(f"{path}: force signals for cables {sorted(fs)}; give force_0..force_{m - 1} or none")
    for i in range(m):
        loc = where.get(f"motor_length_{i}")
        if loc is not None and loc[0].signals[loc[1]].not_available is not None:
            problems.append(f"{path}: motor_length_{i} has a not_available value; motor lengths are always required")
    pose = [n for n in _POSE_SIGNALS if n in where]
    if pose and len(pose) != len(_POSE_SIGNALS):
        missing = [n for n in _POSE_SIGNALS if n not in where]
        problems.append(f"{path}: pose signals {missing} are missing; give all seven or none")
    ids: dict[tuple[int, bool], str] = {}
    for codec in ([sync] if sync else []) + data:
        key = (codec.frame_id, codec.is_extended)
        if key in ids:
            problems.append(f"{path}: messages {ids[key]} and {codec.name} share id 0x{codec.frame_id:X}")
        ids[key] = codec.name
    if problems:
        raise SourceConfigError(f"DBC {path}: {len(problems)} problem(s):\n" + "\n".join(problems))
    assert sync is not None
    layout = CanLayout(
        path=path, db=db, n_cables=m, sync=sync, data=data, counter_bits=cbits, seq_bits=seq_bits,
        has_force=bool(fs), has_pose=bool(pose), has_temperature="temperature" in where,
        by_id={(c.frame_id, c.is_extended): c for c in [sync, *data]}, where=where, fd=any_fd,
    )
    layout.tick = _TickCodec(layout)
    if isinstance(dbc, CanDatabase):
        cache = getattr(db, _CACHE_ATTR, None)
        if cache is None:
            cache = {}
            try:
                setattr(db, _CACHE_ATTR, cache)
            except AttributeError:  # a database class with __slots__: just do not cache
                pass
        cache[-1 if n_cables is None else n_cables] = layout
    return layout


def _as_layout(db: Union[CanLayout, CanDatabase, str, os.PathLike[str]]) -> CanLayout:
    return db if isinstance(db, CanLayout) else load_can_layout(db)


# --------------------------------------------------------------------------------------
# the tick codec: all frames of a tick in one plan
# --------------------------------------------------------------------------------------


def _get(tick: Any, key: str) -> Any:
    if isinstance(tick, Mapping):
        return tick.get(key)
    return getattr(tick, key, None)


class _TickCodec:
    """Every signal of a tick in one :class:`_BitPlan` over the frames laid end to end
    (data frames in sending order, then SYNC, then one zero pad byte).

    Value order: motor_length_0..m-1, force_0..m-1, the seven pose signals, temperature
    (those the DBC has), t, seq, then the tick_counter of each data frame.
    """

    def __init__(self, lay: CanLayout):
        m = lay.n_cables
        frames = lay.frames
        self.offsets: list[int] = []
        off = 0
        for c in frames:
            self.offsets.append(off)
            off += c.length
        self.length = off
        at = {c.name: o for c, o in zip(frames, self.offsets)}
        names = [f"motor_length_{i}" for i in range(m)]
        k = m
        self.k_ml = slice(0, m)
        self.k_force: Optional[slice] = None
        self.k_pos: Optional[slice] = None
        self.k_ori: Optional[slice] = None
        self.k_pose: Optional[slice] = None
        self.k_temp: Optional[int] = None
        if lay.has_force:
            names += [f"force_{i}" for i in range(m)]
            self.k_force = slice(k, k + m)
            k += m
        if lay.has_pose:
            names += list(_POSE_SIGNALS)
            self.k_pos, self.k_ori, self.k_pose = slice(k, k + 3), slice(k + 3, k + 7), slice(k, k + 7)
            k += 7
        self.n_vectors = k  # values that come from the tick's arrays
        if lay.has_temperature:
            names.append("temperature")
            self.k_temp = k
            k += 1
        names += ["t", "seq"]
        self.k_t, self.k_seq = k, k + 1
        placed = [(codec.signals[j], at[codec.name]) for codec, j in (lay.where[n] for n in names)]
        placed += [(c.signals[c.index["tick_counter"]], at[c.name]) for c in lay.data]
        self.names = names + [f"{c.name}.tick_counter" for c in lay.data]
        self.plan = _BitPlan(placed, self.length)
        self.n = len(placed)
        self.m = m
        self.m_shape = (m,)
        self.k_counters = slice(self.k_seq + 1, self.n)
        # the values after the vectors: temperature (NaN: not available), t, seq, counters
        self.tail = np.zeros(self.n - self.n_vectors)
        if self.k_temp is not None:
            self.tail[0] = math.nan
        self.nan_m = np.full(m, math.nan)
        self.nan3 = np.full(3, math.nan)
        self.nan4 = np.full(4, math.nan)
        self.seq_mask = (1 << lay.seq_bits) - 1
        self.cmask = (1 << lay.counter_bits) - 1
        self.meta = [(c.frame_id, c.is_extended, c.is_fd, c.bitrate_switch, o, o + c.length)
                     for c, o in zip(frames, self.offsets)]
        # what the controller adds to a precomputed row every tick: t, seq and the counters,
        # as (first byte, end byte, byte order, shift, mask) in the tick's bytes
        self._stamp_fields = []
        for sig, off in placed[self.k_t:]:
            first, nbytes, shift = sig.span()
            self._stamp_fields.append((off + first, off + first + nbytes,
                                       "little" if sig.little_endian else "big", shift, (1 << sig.length) - 1))
        self._counter_bits: dict[int, int] = {}  # tick counter -> its bits in all data frames
        self.t_signal = placed[self.k_t][0]
        if self.t_signal.is_float:
            raise ValueError("SYNC.t: a float signal; cablesvc sends t as an integer count")

    # ---------------------------------------------------------------- encode
    def values(self, tick: Any) -> tuple[np.ndarray, int]:
        """(physical values in plan order, NaN = not available; seq) of a tick; seq and the
        counters already reduced to their widths."""
        if type(tick) is TickInput:
            seq, t, ml, force = tick.seq, tick.t, tick.motor_length, tick.force
            pos, ori, temp = tick.position, tick.orientation, tick.temperature
        else:
            seq, t, ml, force = _get(tick, "seq"), _get(tick, "t"), _get(tick, "motor_length"), _get(tick, "force")
            pos, ori, temp = _get(tick, "position"), _get(tick, "orientation"), _get(tick, "temperature")
        seq = int(seq)
        ml = np.asarray(ml, dtype=np.float64)
        if ml.shape != self.m_shape:
            raise ValueError(f"tick seq {seq}: motor_length has shape {ml.shape}, the DBC has {self.m} cables")
        parts = [ml]
        if force is not None:
            force = np.asarray(force, dtype=np.float64)
            if force.shape != self.m_shape:
                raise ValueError(f"tick seq {seq}: force has shape {force.shape}, the DBC has {self.m} cables")
        if self.k_force is not None:
            parts.append(self.nan_m if force is None else force)
        if self.k_pos is not None:
            if pos is not None:
                pos = np.asarray(pos, dtype=np.float64)
                if pos.shape != (3,):
                    raise ValueError(f"tick seq {seq}: position has shape {pos.shape}, expected (3,)")
            if ori is not None:
                ori = np.asarray(ori, dtype=np.float64)
                if ori.shape != (4,):
                    raise ValueError(f"tick seq {seq}: orientation has shape {ori.shape}, expected (4,)")
            parts.append(self.nan3 if pos is None else pos)
            parts.append(self.nan4 if ori is None else ori)
        parts.append(self.tail)
        vals = np.concatenate(parts)
        if self.k_temp is not None and temp is not None:
            vals[self.k_temp] = temp
        vals[self.k_t] = t
        vals[self.k_seq] = seq & self.seq_mask
        if self.k_counters.start < self.n:
            vals[self.k_counters] = seq & self.cmask
        return vals, seq

    def encode(self, tick: Any) -> np.ndarray:
        """All frame bytes of the tick, end to end (uint8, ``length``)."""
        vals, seq = self.values(tick)
        return self.plan.pack(vals, f"tick seq {seq}")

    def messages(self, buf: Union[bytes, bytearray]) -> list[can.Message]:
        """The frames of a tick's bytes, as python-can messages in sending order."""
        return [can.Message(arbitration_id=fid, is_extended_id=ext, is_fd=fd, bitrate_switch=brs,
                            data=buf[a:b], check=False)
                for fid, ext, fd, brs, a, b in self.meta]

    def encode_rows(self, motor_length: np.ndarray, force: Optional[np.ndarray] = None,
                    position: Optional[np.ndarray] = None, orientation: Optional[np.ndarray] = None,
                    temperature: Optional[np.ndarray] = None, chunk: int = 4096) -> np.ndarray:
        """Frame bytes of many ticks at once, with t, seq and the counters left 0
        (:meth:`stamp` adds them): (rows, ``length``) uint8. NaN is sent as not_available; a
        row whose position or orientation is all NaN has no pose (both not_available), as
        ``SimulatedController.tick_at`` plays it."""
        ml = np.asarray(motor_length, dtype=np.float64)
        rows = ml.shape[0]
        if ml.shape[1:] != self.m_shape:
            raise ValueError(f"motor_length has shape {ml.shape}, the DBC has {self.m} cables")
        out = np.empty((rows, self.length), dtype=np.uint8)
        base = np.concatenate([np.zeros(self.n_vectors), self.tail])
        for a in range(0, rows, chunk):
            b = min(rows, a + chunk)
            vals = np.tile(base, (b - a, 1))
            vals[:, self.k_ml] = ml[a:b]
            if self.k_force is not None:
                vals[:, self.k_force] = math.nan if force is None else force[a:b]
            if self.k_pos is not None:
                if position is None or orientation is None:
                    vals[:, self.k_pose] = math.nan
                else:
                    p = np.asarray(position[a:b], np.float64)
                    q = np.asarray(orientation[a:b], np.float64)
                    gone = (np.isnan(p).all(axis=1) | np.isnan(q).all(axis=1))[:, None]
                    vals[:, self.k_pos] = np.where(gone, math.nan, p)
                    vals[:, self.k_ori] = np.where(gone, math.nan, q)
            if self.k_temp is not None and temperature is not None:
                vals[:, self.k_temp] = temperature[a:b]
            out[a:b] = self.plan.pack(vals, f"rows {a}-{b - 1}")
        return out

    def _place(self, v: int, a: int, b: int, order: str, shift: int, mask: int) -> int:
        """Field value ``v`` as bits of the tick's bytes read as one little-endian integer."""
        if order == "little":
            return (v & mask) << (8 * a + shift)
        return int.from_bytes(((v & mask) << shift).to_bytes(b - a, "big"), "little") << (8 * a)

    def stamp(self, row: Union[np.ndarray, bytes, int], seq: int, t: float) -> bytes:
        """A row of :meth:`encode_rows` (its bytes, or those read as one little-endian
        integer) with this tick's t, seq and counters: the tick's bytes, equal to
        :meth:`encode` of the tick. A few integer operations, no numpy."""
        s = self.t_signal
        raw = round((t - s.offset) / s.scale)
        if not s.raw_min <= raw <= s.raw_max:
            raise ValueError(f"tick seq {seq}: signal t: {t!r} is outside the range of the DBC")
        if not isinstance(row, int):
            row = int.from_bytes(row.tobytes() if isinstance(row, np.ndarray) else row, "little")
        c = seq & self.cmask
        counters = self._counter_bits.get(c)
        if counters is None:
            counters = self._counter_bits[c] = sum(
                (self._place(c, *f) for f in self._stamp_fields[2:]), 0)
        word = (row | counters | self._place(raw, *self._stamp_fields[0])
                | self._place(seq & self.seq_mask, *self._stamp_fields[1]))
        return word.to_bytes(self.length, "little")

    # ---------------------------------------------------------------- decode
    def decode(self, buf: Union[bytes, bytearray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(raw values, physical values, not_available mask) of a tick's bytes plus the pad byte."""
        plan = self.plan
        x = plan.words(buf)
        v = plan.phys(x)
        return x, v, plan.not_available(x, v)


# --------------------------------------------------------------------------------------
# encoding
# --------------------------------------------------------------------------------------


def encode_tick(db: Union[CanLayout, CanDatabase, str, os.PathLike[str]], tick: Any) -> list[can.Message]:
    """The frames of one tick, in sending order (data frames, then SYNC).

    ``db``: a :class:`CanLayout`, a cantools database or a DBC path. ``tick``: anything
    with the :class:`~cablesvc.sources.base.TickInput` fields (attributes or dict keys:
    seq, t [s], motor_length [m], position [m], orientation, force [N], temperature
    [deg C]); None (or NaN) for a part is sent as ``not_available``. ``seq`` is sent
    modulo 2**seq_bits. Raises ValueError naming the signal when a value does not fit.
    Pure: no bus, no clock. CAN FD messages come out with ``is_fd`` (and
    ``bitrate_switch`` from the DBC's CANFD_BRS, default on).
    """
    tc: _TickCodec = _as_layout(db).tick
    return tc.messages(tc.encode(tick).tobytes())


# --------------------------------------------------------------------------------------
# assembling
# --------------------------------------------------------------------------------------


class _Partial:
    """A tick whose SYNC has not come yet: bus time of its first frame, how many data
    frames are in, and the frames' bytes by slot (then a place for the SYNC and the pad)."""

    __slots__ = ("first", "count", "frames")

    def __init__(self, first: float, frames: list[Any]):
        self.first = first
        self.count = 0
        self.frames = frames


@dataclass
class _Dead:
    since: float  # bus time at which the tick was rejected [s]
    late: int = 0


class _Slot:
    """Where one message goes in a tick, and where its tick_counter (SYNC: seq) sits."""

    __slots__ = ("index", "codec", "length", "is_fd", "is_sync", "fast", "b0", "b1", "order", "shift", "mask")

    def __init__(self, index: int, codec: FrameCodec, counter: _Signal, is_sync: bool):
        self.index = index
        self.codec = codec
        self.length = codec.length
        self.is_fd = codec.is_fd
        self.is_sync = is_sync
        first, nbytes, shift = counter.span()
        self.b0, self.b1 = first, first + nbytes
        self.order: Literal["little", "big"] = "little" if counter.little_endian else "big"
        self.shift = shift
        self.mask = (1 << counter.length) - 1
        self.fast = counter.length == 8 and shift == 0

    def read(self, data: Union[bytes, bytearray]) -> int:
        if self.fast:
            return data[self.b0]
        return (int.from_bytes(data[self.b0:self.b1], self.order) >> self.shift) & self.mask


_PAD = b"\0"


class TickAssembler:
    """Frames in, complete ticks out (pure: all times come from the caller / the frames).

    :meth:`feed` takes one received :class:`can.Message` and returns what it completed or
    refused: :class:`~cablesvc.sources.base.TickInput` (not yet validated; ``stamp_ns`` =
    ``now_ns``, default ``time.monotonic_ns()``) and :class:`~cablesvc.sources.base.Rejection`
    items. Reasons: ``missing_frames`` (the message names the missing DBC messages),
    ``bad_frame`` (unknown id, wrong length, classic/FD mismatch, error/remote frame),
    ``late_frame`` (frames of a tick that was already rejected at its deadline),
    ``nonfinite`` (a tick in which some but not all forces, or some but not all pose values,
    are ``not_available``).

    Deadline: a tick whose SYNC has not arrived ``deadline_s`` [s] after its first frame is
    rejected. Time is *bus time*, the frames' ``timestamp`` [s] (python-can: receive time,
    ``time.time()`` scale), so a receive thread that falls behind and then reads a burst of
    queued frames does not reject ticks whose frames were all there in time. Each
    :meth:`feed` checks the deadlines against the newest frame time seen (only when the
    oldest pending tick may be due);
    :meth:`expire` checks them against ``bus_time`` (default ``time.time()``) when the bus
    is quiet. A frame without a timestamp (0) gets ``time.time()``.

    Clock steps: a frame time more than ``deadline_s`` + :data:`CLOCK_STEP_MARGIN_S` earlier
    than the newest frame time seen cannot be a queued or late frame (those come in time
    order): the clock was stepped back (NTP). The assembler re-bases its bus time on the new
    clock (pending ticks keep their age) and returns one ``clock_step`` item (a
    :class:`~cablesvc.sources.base.Rejection` whose reason is in :data:`EVENT_REASONS`: an
    event, nothing was refused), so ticks keep flowing instead of all expiring until the
    clock catches up.

    Cost: a data frame is a dict lookup, a counter read and a list store (its bytes are
    kept as they came); the SYNC decodes the whole tick with one numpy gather
    (:class:`FrameCodec` plans laid end to end).
    """

    def __init__(self, db: Union[CanLayout, CanDatabase, str, os.PathLike[str]], deadline_s: float = 0.005):
        self.layout = _as_layout(db)
        if not (math.isfinite(deadline_s) and deadline_s > 0):
            raise ValueError(f"deadline_s must be > 0 s, got {deadline_s!r}")
        self.deadline = float(deadline_s)
        lay = self.layout
        self._tick: _TickCodec = lay.tick
        self._cmask = (1 << lay.counter_bits) - 1
        self._pending: dict[int, _Partial] = {}
        self._dead: dict[int, _Dead] = {}
        self._bus_now = -math.inf
        self._earliest = math.inf  # <= the first-frame time of every pending or dead tick
        self._n_data = len(lay.data)
        self._std: dict[int, _Slot] = {}
        self._ext: dict[int, _Slot] = {}
        for i, c in enumerate(lay.data):
            (self._ext if c.is_extended else self._std)[c.frame_id] = _Slot(
                i, c, c.signals[c.index["tick_counter"]], False)
        sync = lay.sync
        (self._ext if sync.is_extended else self._std)[sync.frame_id] = _Slot(
            self._n_data, sync, sync.signals[sync.index["seq"]], True)
        self._blank: list[Any] = [None] * (self._n_data + 1) + [_PAD]

    @property
    def pending(self) -> int:
        """Number of ticks started (some frames in) and not yet closed or expired."""
        return len(self._pending)

    def next_deadline(self) -> Optional[float]:
        """Bus time [s] at which :meth:`expire` next has something to do (None: nothing
        pending). Never later than the true time; possibly earlier (then :meth:`expire`
        finds nothing and corrects it)."""
        if not self._pending and not self._dead:
            return None
        return self._earliest + self.deadline

    def _missing(self, p: Optional[_Partial]) -> list[str]:
        if p is None:
            return self.layout.data_names
        return [c.name for c, f in zip(self.layout.data, p.frames) if f is None]

    def feed(self, msg: can.Message, now_ns: Optional[int] = None) -> list[Union[TickInput, Rejection]]:
        """Take one frame; return the ticks it completed and the rejections it caused
        (including ticks whose deadline passed by this frame's time)."""
        ts = msg.timestamp or time.time()
        step: Optional[Rejection] = None
        if ts > self._bus_now:
            self._bus_now = ts
        elif ts < self._bus_now - self.deadline - CLOCK_STEP_MARGIN_S:
            step = self._rebase(ts)
        slot = (self._ext if msg.is_extended_id else self._std).get(msg.arbitration_id)
        data = msg.data
        if (slot is None or msg.is_error_frame or msg.is_remote_frame or len(data) != slot.length
                or msg.is_fd != slot.is_fd):
            out: list[Union[TickInput, Rejection]] = [self._bad_frame(msg, slot)]
        elif slot.is_sync:
            out = self._close(slot, data, now_ns)
        else:
            c = data[slot.b0] if slot.fast else slot.read(data)
            out = []
            if self._dead and c in self._dead:
                self._dead[c].late += 1
            else:
                p = self._pending.get(c)
                if p is None:
                    p = self._start(c, ts)
                elif p.frames[slot.index] is not None:
                    # a second frame of the same message with this counter: the earlier tick
                    # never got its SYNC. Reject it and start over with this frame.
                    out.append(Rejection(
                        "missing_frames",
                        f"tick with tick_counter {c}: no SYNC before the next {slot.codec.name} with the same "
                        f"counter; missing: {', '.join(self._missing(p) + [self.layout.sync.name])}",
                    ))
                    p = self._start(c, ts)
                p.frames[slot.index] = bytes(data)  # a copy: the caller may reuse the message
                p.count += 1
        if self._bus_now - self._earliest > self.deadline:
            out.extend(self.expire(bus_time=self._bus_now))
        if step is not None:
            out.insert(0, step)
        return out

    def _rebase(self, ts: float) -> Rejection:
        """The clock went back: move bus time to ``ts``, shifting pending and rejected ticks'
        times with it (they keep their age)."""
        shift = ts - self._bus_now
        for p in self._pending.values():
            p.first += shift
        for d in self._dead.values():
            d.since += shift
        self._earliest += shift
        self._bus_now = ts
        return Rejection("clock_step",
                         f"frame time went back {-shift:.3f} s (clock stepped back?): deadlines re-based on the "
                         f"new clock, {len(self._pending)} pending tick(s) kept")

    def _start(self, counter: int, ts: float) -> _Partial:
        p = self._pending[counter] = _Partial(ts, self._blank.copy())
        if ts < self._earliest:
            self._earliest = ts
        return p

    def _bad_frame(self, msg: can.Message, slot: Optional[_Slot]) -> Rejection:
        if msg.is_error_frame:
            return Rejection("bad_frame", f"error frame on the bus (id 0x{msg.arbitration_id:X})")
        if slot is None:
            width = 8 if msg.is_extended_id else 3
            return Rejection("bad_frame",
                             f"unknown CAN id 0x{msg.arbitration_id:0{width}X}"
                             f"{' (extended)' if msg.is_extended_id else ''}: not in {self.layout.path}")
        codec = slot.codec
        if msg.is_remote_frame:
            return Rejection("bad_frame", f"{codec.name} (0x{codec.frame_id:X}): remote frame, expected data")
        if bool(msg.is_fd) != codec.is_fd:
            want = "a CAN FD frame" if codec.is_fd else "a classic CAN frame"
            return Rejection("bad_frame",
                             f"{codec.name} (0x{codec.frame_id:X}): {len(msg.data)} data bytes in "
                             f"{'a CAN FD' if msg.is_fd else 'a classic'} frame, the DBC says {want} "
                             f"of {codec.length} bytes")
        return Rejection("bad_frame",
                         f"{codec.name} (0x{codec.frame_id:X}): {len(msg.data)} data bytes"
                         f"{' (CAN FD)' if msg.is_fd else ''}, the DBC says {codec.length}")

    def _close(self, slot: _Slot, data: Union[bytes, bytearray],
               now_ns: Optional[int]) -> list[Union[TickInput, Rejection]]:
        seq = slot.read(data)
        if not self._n_data:
            return [self._build([data, _PAD], seq, now_ns)]
        counter = seq & self._cmask
        p = self._pending.pop(counter, None)
        if p is None:
            return [self._orphan_sync(data, seq, counter)]
        if not self._pending and not self._dead:
            self._earliest = math.inf
        if p.count != self._n_data:
            return [Rejection("missing_frames",
                              f"tick seq {seq} (t {self._t_of(data)!r} s): missing {', '.join(self._missing(p))} "
                              f"at {self.layout.sync.name}")]
        frames = p.frames
        frames[-2] = data
        return [self._build(frames, seq, now_ns)]

    def _t_of(self, sync_data: Union[bytes, bytearray]) -> float:
        return self.layout.sync.decode(sync_data)["t"]

    def _orphan_sync(self, data: Union[bytes, bytearray], seq: int, counter: int) -> Rejection:
        name = self.layout.sync.name
        dead = self._dead.pop(counter, None)
        if not self._pending and not self._dead:
            self._earliest = math.inf
        if dead is not None:
            return Rejection("late_frame",
                             f"tick seq {seq}: {name} and {dead.late} other frame(s) arrived after the "
                             f"{self.deadline * 1e3:g} ms deadline; the tick was already rejected")
        return Rejection("missing_frames",
                         f"tick seq {seq} (t {self._t_of(data)!r} s): {name} arrived but no other frame of the tick; "
                         f"missing: {', '.join(self._missing(None))}")

    def _build(self, frames: list[Any], seq: int, now_ns: Optional[int]) -> Union[TickInput, Rejection]:
        tc = self._tick
        _x, v, na = tc.decode(b"".join(frames))
        force = position = orientation = None
        temperature = None
        if np.count_nonzero(na):
            return self._build_partial(v, na, seq, now_ns)
        if tc.k_force is not None:
            force = v[tc.k_force]
        if tc.k_pos is not None:
            position, orientation = v[tc.k_pos], v[tc.k_ori]
        if tc.k_temp is not None:
            temperature = float(v[tc.k_temp])
        return TickInput(seq=seq, t=float(v[tc.k_t]), motor_length=v[tc.k_ml], position=position,
                         orientation=orientation, force=force, temperature=temperature,
                         stamp_ns=time.monotonic_ns() if now_ns is None else now_ns)

    def _build_partial(self, v: np.ndarray, na: np.ndarray, seq: int,
                       now_ns: Optional[int]) -> Union[TickInput, Rejection]:
        """A tick with some values not_available: all forces or none, a whole pose or none."""
        tc = self._tick
        t = float(v[tc.k_t])
        v[na] = math.nan
        force = position = orientation = None
        temperature = None
        if tc.k_force is not None:
            fna = na[tc.k_force]
            if fna.any() and not fna.all():
                names = [f"force_{i} ({self.layout.where[f'force_{i}'][0].name})" for i in np.flatnonzero(fna)]
                return Rejection("nonfinite",
                                 f"tick seq {seq} (t {t!r} s): {', '.join(names)} {NOT_AVAILABLE} while other "
                                 f"cables have a force; a tick has all forces or none")
            if not fna.any():
                force = v[tc.k_force]
        if tc.k_pose is not None:
            pna = na[tc.k_pose]
            if pna.any() and not pna.all():
                names = [f"{_POSE_SIGNALS[k]} ({self.layout.where[_POSE_SIGNALS[k]][0].name})"
                         for k in np.flatnonzero(pna)]
                return Rejection("nonfinite",
                                 f"tick seq {seq} (t {t!r} s): {', '.join(names)} {NOT_AVAILABLE} while the rest "
                                 f"of the pose is given; a pose has all seven values or none")
            if not pna.any():
                position, orientation = v[tc.k_pos], v[tc.k_ori]
        if tc.k_temp is not None and not na[tc.k_temp]:
            temperature = float(v[tc.k_temp])
        return TickInput(seq=seq, t=t, motor_length=v[tc.k_ml], position=position, orientation=orientation,
                         force=force, temperature=temperature,
                         stamp_ns=time.monotonic_ns() if now_ns is None else now_ns)

    def expire(self, bus_time: Optional[float] = None) -> list[Rejection]:
        """Reject the ticks whose SYNC did not come within the deadline of their first frame,
        judged at ``bus_time`` [s] (default ``time.time()``: call it when the bus is quiet)."""
        now = time.time() if bus_time is None else float(bus_time)
        out: list[Rejection] = []
        earliest = math.inf
        if self._pending:
            for counter in [c for c, p in self._pending.items() if now - p.first > self.deadline]:
                p = self._pending.pop(counter)
                out.append(Rejection(
                    "missing_frames",
                    f"tick with tick_counter {counter}: no {self.layout.sync.name} within "
                    f"{self.deadline * 1e3:g} ms of its first frame; missing: "
                    f"{', '.join(self._missing(p) + [self.layout.sync.name])}",
                ))
                self._dead[counter] = _Dead(now)
            for p in self._pending.values():
                earliest = min(earliest, p.first)
        if self._dead:
            for counter in [c for c, d in self._dead.items() if now - d.since > self.deadline]:
                d = self._dead.pop(counter)
                if d.late:
                    out.append(Rejection(
                        "late_frame",
                        f"tick with tick_counter {counter}: {d.late} frame(s) arrived after its deadline "
                        f"and no {self.layout.sync.name}; the tick was already rejected",
                    ))
            for d in self._dead.values():
                earliest = min(earliest, d.since)
        self._earliest = earliest
        return out


# --------------------------------------------------------------------------------------
# buses
# --------------------------------------------------------------------------------------


def open_bus(bus_config: Mapping[str, Any]) -> can.BusABC:
    """Open a python-can bus from ``{"interface", "channel", "bitrate"?, "fd"?, "bus_kwargs"?}``
    (the fields of :class:`CanSourceConfig`; ``bitrate`` in bit/s; ``fd``: a CAN FD bus,
    python-can ``Bus(fd=True)``)."""
    kwargs = dict(bus_config.get("bus_kwargs") or {})
    if bus_config.get("bitrate") is not None:
        kwargs["bitrate"] = int(bus_config["bitrate"])
    if bus_config.get("fd"):
        kwargs["fd"] = True
    return can.Bus(interface=bus_config["interface"], channel=bus_config["channel"], **kwargs)


def _grow_receive_buffer(bus: can.BusABC, size: int = 4 << 20) -> None:
    """Best effort: enlarge the kernel receive buffer of a socket-based bus (udp_multicast,
    socketcan) so that bursts of frames are not dropped while the receive thread is busy."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, AttributeError, OSError):
        return
    if not isinstance(fd, int) or fd < 0:
        return
    try:
        s = socket.socket(fileno=os.dup(fd))
    except OSError:
        return
    try:
        for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
            if opt is None:
                continue
            try:
                s.setsockopt(socket.SOL_SOCKET, opt, size)
                break
            except OSError:
                continue
    finally:
        s.close()


def _ipv6_multicast_works(group: str) -> bool:
    try:
        s = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    except OSError:
        return False
    try:
        import struct

        s.bind(("", 0))
        s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP,
                     socket.inet_pton(socket.AF_INET6, group) + struct.pack("@I", 0))
        return True
    except OSError:
        return False
    finally:
        s.close()


def free_udp_port() -> int:
    """A UDP port that is free right now on this host (for tests that need their own bus)."""
    for family, addr in ((socket.AF_INET6, "::"), (socket.AF_INET, "")):
        try:
            with socket.socket(family, socket.SOCK_DGRAM) as s:
                s.bind((addr, 0))
                return int(s.getsockname()[1])
        except OSError as exc:
            if exc.errno not in (errno.EAFNOSUPPORT, errno.EADDRNOTAVAIL):
                raise
    raise OSError("no UDP port available")


def loopback_bus_config(port: Optional[int] = None, fd: bool = False) -> dict[str, Any]:
    """A CAN bus that crosses processes but never leaves this host.

    python-can's ``udp_multicast`` interface on the IPv6 interface-local multicast group
    :data:`LOOPBACK_GROUP_IPV6` (scope ff11::/16: the kernel delivers it to sockets on this
    host and never transmits it on a link) with hop limit 0. Where IPv6 multicast is not
    available, the IPv4 group :data:`LOOPBACK_GROUP_IPV4` with TTL 0 (the kernel loops the
    datagram back to local members and sends none out). ``port`` [UDP]: default
    :data:`LOOPBACK_PORT`; give each independent bus its own (see :func:`free_udp_port`).
    ``fd``: carry CAN FD frames (python-can's udp_multicast ``fd`` argument; with
    ``fd=False`` that interface refuses to send FD frames and silently drops received ones).
    Needs the ``msgpack`` package (python-can's ``multicast`` extra).

    Returns ``{"interface", "channel", "bitrate": None, "fd", "bus_kwargs"}``: the fields of
    :class:`CanSourceConfig` and the ``bus_config`` of the simulated CAN controller.
    """
    group = LOOPBACK_GROUP_IPV6 if _ipv6_multicast_works(LOOPBACK_GROUP_IPV6) else LOOPBACK_GROUP_IPV4
    return {
        "interface": "udp_multicast",
        "channel": group,
        "bitrate": None,
        "fd": bool(fd),
        "bus_kwargs": {"port": int(LOOPBACK_PORT if port is None else port), "hop_limit": 0, "fd": bool(fd)},
    }


# --------------------------------------------------------------------------------------
# the source
# --------------------------------------------------------------------------------------


class CanSourceConfig(BaseModel):
    """``kind = "can"``: a python-can bus carrying the frames of a DBC.

    ``interface``/``channel``: as for ``can.Bus`` (``socketcan``/``can0`` beside a real
    controller; ``virtual`` for one process; ``udp_multicast`` for tests across processes);
    ``bitrate`` [bit/s] (None: leave the interface's setting); ``fd``: a CAN FD bus
    (python-can ``Bus(fd=True)``; needed for a DBC with CAN FD frames); ``dbc``: the DBC
    file (None: ``<robot>.dbc``, or ``<robot>-fd.dbc`` with ``fd``, found like robot files);
    ``deadline_s`` [s]: how long after its first frame a tick may wait for its SYNC;
    ``bus_kwargs``: more ``can.Bus`` keywords (e.g. ``can_filters`` on a shared bus,
    ``port``/``hop_limit`` for udp_multicast, ``data_bitrate`` for some FD interfaces).
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["can"] = "can"
    interface: str = "virtual"
    channel: Union[str, int] = "cablesvc"
    bitrate: Optional[int] = Field(default=None, gt=0)
    fd: bool = False
    dbc: Optional[Path] = None
    deadline_s: float = Field(default=0.005, gt=0, allow_inf_nan=False)
    bus_kwargs: dict[str, Any] = Field(default_factory=dict)


class CanSource(ThreadedSource):
    """Ticks from a CAN bus (see the module docstring for the frames).

    A receive thread reads the bus (``recv(timeout)``, then ``recv(0)`` until nothing is
    queued), feeds :class:`TickAssembler`, validates each tick as soon as its SYNC completes
    it and queues it for :meth:`recv`. ``config.fd``: the bus is opened with ``fd=True``
    and the default DBC is ``<robot>-fd.dbc``; a DBC with CAN FD frames needs it. A bus
    error is reported (``disconnected``) and the bus is reopened with backoff (0.05 s
    doubling to 2 s, reset once frames flow) until it works again (``reconnected``: one pair
    per outage) or the source is closed; the open happens outside the lock :meth:`close`
    takes, so a slow adapter does not hold up :meth:`close`. cablesvc only listens:
    it never transmits on the bus.
    """

    kind: ClassVar[str] = "can"

    def __init__(self, robot: Robot, config: CanSourceConfig):
        if config.dbc is not None:
            self._dbc_path: Path = config.dbc
        else:
            try:
                self._dbc_path = find_robot_companion(robot, dbc_suffix(config.fd))
            except SourceConfigError as exc:
                raise SourceConfigError(f"source.dbc: {exc}") from None
        self.layout = load_can_layout(self._dbc_path, robot.n_cables)
        if self.layout.fd and not config.fd:
            fd_names = [c.name for c in self.layout.frames if c.is_fd]
            raise SourceConfigError(
                f"source.fd: {self._dbc_path} describes CAN FD frames ({', '.join(fd_names)}); set fd = true "
                f"(a classic bus cannot carry them)"
            )
        super().__init__(robot, config)
        self.config: CanSourceConfig = config
        self.assembler = TickAssembler(self.layout, config.deadline_s)
        self._bus: Optional[can.BusABC] = None
        self._bus_lock = threading.Lock()
        self._down_since: Optional[float] = None  # monotonic time the current outage began
        self._reopen_attempts = 0
        self._opening = False  # the receive thread is inside _open_bus

    def _seq_bits(self) -> Optional[int]:
        return self.layout.seq_bits

    @property
    def label(self) -> str:
        return f"can {self.config.interface}:{self.config.channel}"

    def _bus_config(self) -> dict[str, Any]:
        return {"interface": self.config.interface, "channel": self.config.channel,
                "bitrate": self.config.bitrate, "fd": self.config.fd, "bus_kwargs": self.config.bus_kwargs}

    def _open_bus(self) -> can.BusABC:
        kwargs = dict(self.config.bus_kwargs)
        kwargs.setdefault("receive_own_messages", False)
        bus = open_bus({**self._bus_config(), "bus_kwargs": kwargs})
        _grow_receive_buffer(bus)
        return bus

    def open(self) -> None:
        """Open the bus and start the receive thread.

        A configuration python-can cannot use at all (unknown interface, missing driver
        package, bad keyword) raises :class:`SourceConfigError`. A bus that exists in
        principle but is not there yet (``can0`` down or absent) is reported as
        ``disconnected`` and opened by the receive thread as soon as it works.
        """
        if self._opened:
            return
        try:
            self._bus = self._open_bus()
        except (can.CanInterfaceNotImplementedError, ImportError, TypeError, ValueError) as exc:
            raise SourceConfigError(
                f"source.interface: cannot use interface {self.config.interface!r} channel "
                f"{self.config.channel!r}: {exc}"
            ) from None
        except (can.CanError, OSError) as exc:
            if isinstance(exc, OSError) and exc.errno == errno.EAFNOSUPPORT:
                raise SourceConfigError(
                    f"source.interface: {self.config.interface!r} is not supported by this kernel: {exc}"
                ) from None
            self._bus = None
            self._down_since = time.monotonic()
            self._report("disconnected", f"cannot open the bus yet: {exc}; retrying with backoff up to 2 s",
                         kind="event")
        self._opened = True
        self._start_thread(self._run, f"cablesvc-can-{self.config.channel}")

    def _run(self) -> None:
        backoff = 0.05
        asm = self.assembler
        while not self._stop.is_set():
            bus = self._bus
            if bus is None:
                bus = self._reopen()
                if bus is None:
                    if self._stop.wait(backoff):
                        return
                    backoff = min(2.0, backoff * 2)
                    continue
            nxt = asm.next_deadline()
            timeout = 0.1 if nxt is None else max(0.0, min(0.1, nxt - time.time() + 1e-4))
            try:
                msg = bus.recv(timeout=timeout)
            except Exception as exc:  # noqa: BLE001 - python-can raises CanError and OSError
                self._bus_failed(bus, exc)
                if self._stop.wait(backoff):  # a bus that opens but fails at once must not spin
                    return
                backoff = min(2.0, backoff * 2)
                continue
            if self._down_since is not None:  # it opened and a receive worked: the outage is over
                self._bus_back()
            if msg is None:  # the bus is quiet: nothing is queued, so what is missing now is late
                self._handle(asm.expire())
                continue
            backoff = 0.05  # frames flow again
            # drain what is queued without waiting, handing each tick on as it completes
            while msg is not None:
                events = asm.feed(msg, time.monotonic_ns())
                if events:
                    self._handle(events)
                if self._stop.is_set():
                    return
                try:
                    msg = bus.recv(0.0)
                except Exception as exc:  # noqa: BLE001
                    self._bus_failed(bus, exc)
                    if self._stop.wait(backoff):
                        return
                    backoff = min(2.0, backoff * 2)
                    break

    def _reopen(self) -> Optional[can.BusABC]:
        """Open the bus (outside ``_bus_lock``: a slow open must not hold up :meth:`close`)
        and install it; None when it failed or the source is closing."""
        self._reopen_attempts += 1
        self._opening = True
        try:
            bus = self._open_bus()
        except Exception:  # noqa: BLE001 - any driver error: retry
            return None
        finally:
            self._opening = False
        with self._bus_lock:
            stopping = self._stop.is_set()
            if not stopping:
                self._bus = bus
        if stopping:  # close() came while it was opening: nobody else will shut it down
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001
                pass
            return None
        return bus

    def _bus_back(self) -> None:
        down = time.monotonic() - (self._down_since or time.monotonic())
        tries = self._reopen_attempts
        self._report("reconnected",
                     f"bus working again after {down:.2f} s ({tries} reopen attempt{'s' if tries != 1 else ''})",
                     kind="event")
        self._down_since = None
        self._reopen_attempts = 0

    def _handle(self, events: list[Union[TickInput, Rejection]]) -> None:
        for ev in events:
            if type(ev) is TickInput:
                self._deliver(ev)
            elif ev.reason in EVENT_REASONS:
                self._report(ev.reason, ev.message, kind="event")
            else:
                self._report(ev.reason, ev.message)

    def _bus_failed(self, bus: can.BusABC, exc: BaseException) -> None:
        """Drop a bus whose receive failed; report ``disconnected`` once per outage (a bus
        that reopens but fails again at once is the same outage)."""
        with self._bus_lock:
            if self._bus is bus:
                self._bus = None
        try:
            bus.shutdown()
        except Exception:  # noqa: BLE001
            pass
        if self._stop.is_set() or self._down_since is not None:
            return
        self._down_since = time.monotonic()
        self._reopen_attempts = 0
        self._report("disconnected", f"bus error: {exc!r}; reopening with backoff up to 2 s", kind="event")

    def close(self) -> None:
        """Stop the receive thread and shut the bus down (idempotent, < 1 s)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        # a thread inside a (possibly slow) bus open shuts that bus down itself when it returns
        self._join_thread(0.1 if self._opening else 0.9)
        with self._bus_lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001
                pass
