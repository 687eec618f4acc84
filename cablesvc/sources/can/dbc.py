"""The cablesvc CAN frame layouts, written as DBC text (:func:`make_dbc`), and their ids.

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

Any other DBC that follows the conventions checked by
:func:`~cablesvc.sources.can.layout.load_can_layout` works as well: the DBC is the single
source of truth for every position and scale.
"""

from __future__ import annotations

from typing import Sequence

from cablesvc.config.robot import Robot

__all__ = [
    "CABLE_BASE_ID",
    "FD_FRAME_CABLES",
    "FD_LENGTHS",
    "FD_SYNC_CABLES",
    "NOT_AVAILABLE",
    "PLATFORM_FD_ID",
    "PLATFORM_IDS",
    "POSE_SIGNALS",
    "SYNC_ID",
    "dbc_suffix",
    "make_dbc",
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
#: The seven pose signals, in the order a tick's values keep them.
POSE_SIGNALS = ("position_x", "position_y", "position_z",
                 "orientation_qx", "orientation_qy", "orientation_qz", "orientation_qw")


def dbc_suffix(fd: bool) -> str:
    """The file-name suffix of a robot's default DBC: ``-fd.dbc`` for CAN FD, else ``.dbc``."""
    return "-fd.dbc" if fd else ".dbc"


# --------------------------------------------------------------------------------------
# DBC generation
# --------------------------------------------------------------------------------------


def _q(s: str) -> str:
    return s.replace("\\", "/").replace('"', "'")


class _DbcWriter:
    """The parts of a DBC text as its messages are added: ``BO_``/``SG_`` blocks, ``CM_``
    comments, ``VAL_`` tables and the ids in order; :meth:`text` puts them together."""

    def __init__(self) -> None:
        self.bo: list[str] = []
        self.cm: list[str] = []
        self.val: list[str] = []
        self.ids: list[int] = []

    def message(self, can_id: int, name: str, length: int, comment: str,
                signals: list[tuple[str, str, str, str]]) -> None:
        """One message of ``length`` bytes; ``signals``: (name, DBC spec, unit, comment)."""
        lines = [f"BO_ {can_id} {name}: {length} CONTROLLER"]
        for sname, spec, unit, scomment in signals:
            lines.append(f' SG_ {sname} : {spec} "{unit}" CABLESVC')
            self.cm.append(f'CM_ SG_ {can_id} {sname} "{_q(scomment)}";')
        self.bo.append("\n".join(lines))
        self.cm.append(f'CM_ BO_ {can_id} "{_q(comment)}";')
        self.ids.append(can_id)

    def text(self, version: str, new_symbols: list[str], file_comment: str, attrs: Sequence[str] = ()) -> str:
        """The DBC: header (``version`` line, ``NS_`` with ``new_symbols``, nodes), messages,
        comments, ``attrs`` (attribute definitions and values), value tables."""
        head = [version, "", "NS_ :", *[f"\t{s}" for s in new_symbols], "",
                "BS_:", "", "BU_: CONTROLLER CABLESVC", ""]
        comments = [f'CM_ "{_q(file_comment)}";', 'CM_ BU_ CONTROLLER "the robot controller (sender)";',
                    'CM_ BU_ CABLESVC "cablesvc (receiver, never transmits)";'] + self.cm
        return ("\n".join(head) + "\n" + "\n\n".join(self.bo) + "\n\n"
                + "\n".join([*comments, *attrs, *self.val]) + "\n")


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
    w = _DbcWriter()
    val = w.val

    def msg(can_id: int, name: str, comment: str, signals: list[tuple[str, str, str, str]]) -> None:
        w.message(can_id, name, 8, comment, signals)

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
    file_comment = (
        f"cablesvc CAN layout for robot {robot.name} ({m} cables). Classic CAN, 8-byte frames, "
        f"11-bit ids, little-endian (Intel) signals. Per tick: CABLE_0..CABLE_{m - 1}, PLATFORM_X, "
        f"PLATFORM_Y, PLATFORM_Z, PLATFORM_QXY, PLATFORM_QZW, then SYNC ({m + 6} frames). "
        f"Every data frame carries tick_counter = SYNC.seq mod 256. SI units. Generated by "
        f"cablesvc.sources.make_dbc; see docs/sources.md"
    )
    return w.text('VERSION "cablesvc-1"', ["CM_", "VAL_"], file_comment)


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
    w = _DbcWriter()
    val = w.val

    def msg(can_id: int, name: str, nbits: int, comment: str, signals: list[tuple[str, str, str, str]]) -> None:
        w.message(can_id, name, _fd_length((nbits + 7) // 8), comment, signals)

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
    file_comment = (
        f"cablesvc CAN FD layout for robot {robot.name} ({m} cables). CAN FD frames of up to 64 bytes with "
        f"bit rate switch, 11-bit ids, little-endian (Intel) signals; same resolutions as the classic "
        f"layout. Per tick: {', '.join(order[:-1])}, then SYNC ({len(order)} frames). Every data frame "
        f"carries tick_counter = SYNC.seq mod 256. SI units. Generated by "
        f"cablesvc.sources.make_dbc(robot, fd=True); see docs/sources.md"
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
    ] + [f'BA_ "VFrameFormat" BO_ {cid} 14;' for cid in w.ids]
    return w.text('VERSION "cablesvc-fd-1"', ["CM_", "BA_DEF_", "BA_", "VAL_", "BA_DEF_DEF_"], file_comment, attrs)
