"""Reading BVH motion capture: every kind of bad file, units / up / facing detection, and a round trip
through several conventions checked against an independent forward kinematics (scipy's Euler angles
to write, plain rotation matrices to check). Real clips: ../shared/data/bvh (skipped when absent).

The figures and the writer are tests/bvh_factory.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from bvh_factory import FILE_FROM_MER, canonical_fk, human_definition, write_bvh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from mer_data.base.errors import BVHError, MerError
from mer_data.motion.bvh import parse_bvh_bytes, parse_bvh_text, read_bvh, split_joint_name

# ---- a small valid file and every way to break it ----------------------------------------------

SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 10 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 90 0 0 0 0 0 0 0
0 90 0 10 0 0 0 0 0
"""


def test_a_small_file_reads_exactly():
    m = parse_bvh_text(SMALL, "small.bvh", units="cm", up="y", facing="keep")
    assert m.joint_names == ("Hips", "Spine", "Spine_End")
    assert [j.parent for j in m.joints] == [-1, 0, 1] and m.joints[2].end_site
    assert m.joints[1].channels == ("Zrotation", "Xrotation", "Yrotation") and m.joints[1].column == 6
    assert m.values.shape == (2, 9) and m.values[1, 3] == 10.0
    assert m.fps == 30.0 and m.frame_time == 0.0333333 and m.first_data_line == 19
    pos = m.positions()  # Y-up cm -> z-up m: the spine goes up 0.1 m per bone
    np.testing.assert_allclose(pos[0], [[0, 0, 0.9], [0, 0, 1.0], [0, 0, 1.1]], atol=1e-12)
    # frame 2: the root turned 10 degrees about file z (mer x): file y (up) tilts to file -x (mer -y)
    s, c = math.sin(math.radians(10)), math.cos(math.radians(10))
    np.testing.assert_allclose(pos[1, 2] - pos[1, 0], [0, -0.2 * s, 0.2 * c], atol=1e-12)


def _edit(old: str, new: str, text: str = SMALL) -> str:
    assert text.count(old) >= 1, old
    return text.replace(old, new, 1)


FRAME_LINE = "0 90 0 10 0 0 0 0 0\n"
MALFORMED = [  # (id, text, what the message says, line)
    ("empty", "", "not a BVH file: it must start with HIERARCHY, found an empty file", 1),
    ("not a BVH", "name,x,y\n1,2,3\n", "not a BVH file: it must start with HIERARCHY, found 'name,x,y'", 1),
    ("no ROOT", _edit("ROOT Hips", "JOINT Hips"), "expected ROOT after HIERARCHY, found 'JOINT'", 2),
    ("root without name", _edit("ROOT Hips", "ROOT"), "ROOT without a name", 2),
    ("missing brace", _edit("    }\n  }\n}\nMOTION", "    }\n  }\nMOTION"),
     "unbalanced braces: MOTION starts inside joint 'Hips', whose '{' on line 3 is never closed", 15),
    ("extra brace", _edit("}\nMOTION", "}\n}\nMOTION"), "unbalanced braces: a '}' closes nothing", 16),
    ("ends inside", SMALL[: SMALL.index("  }\n}\nMOTION")],
     "unbalanced braces: the file ends inside joint 'Spine', whose '{' on line 7 is never closed", 13),
    ("missing MOTION", SMALL[: SMALL.index("MOTION")], "there is no MOTION section", 15),
    ("second ROOT", _edit("}\nMOTION", "}\nROOT B\n{\nOFFSET 0 0 0\n}\nMOTION"), "a second ROOT", 16),
    ("missing OFFSET", _edit("    OFFSET 0 10 0\n    CHANNELS", "    CHANNELS"),
     "expected 'OFFSET' (first in Spine), found 'CHANNELS'", 8),
    ("short OFFSET", _edit("OFFSET 0 10 0\n    CHANNELS", "OFFSET 0 10\n    CHANNELS"),
     "OFFSET of Spine has 2 numbers, expected 3", 8),
    ("long OFFSET", _edit("OFFSET 0 10 0\n    CHANNELS", "OFFSET 0 10 0 4\n    CHANNELS"),
     "OFFSET of Spine has more than 3 numbers ('4')", 8),
    ("bad OFFSET", _edit("OFFSET 0 10 0", "OFFSET 0 ten 0"), "OFFSET of Spine: 'ten' is not a number", 8),
    ("huge OFFSET", _edit("OFFSET 0 10 0", "OFFSET 0 1e300 0"), "OFFSET of Spine: 1e300 is beyond +-1e+09", 8),
    ("unknown channel", _edit("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation Wrotation"),
     "unknown channel 'Wrotation' in joint 'Spine'", 9),
    ("repeated channel", _edit("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation Zrotation"),
     "channel Zrotation appears twice in joint 'Spine'", 9),
    ("too few channel names", _edit("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation"),
     "CHANNELS of Spine announces 3 channels but lists 2", 9),
    ("too many channel names", _edit("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 2 Zrotation Xrotation Yrotation"),
     "CHANNELS of Spine announces 2 channels but lists more ('Yrotation')", 9),
    ("channel count", _edit("CHANNELS 3", "CHANNELS 7"), "the count '7' is not a number from 0 to 6", 9),
    ("duplicate joint", _edit("JOINT Spine", "JOINT Hips"), "duplicate joint name 'Hips' (also on line 2)", 6),
    ("End Site with channels", _edit("      OFFSET 0 10 0\n    }", "      OFFSET 0 10 0\n      CHANNELS 0\n    }"),
     "an End Site holds only an OFFSET, found 'CHANNELS'", 13),
    ("OFFSET out of place", _edit("    End Site", "    OFFSET 0 0 0\n    End Site"), "OFFSET out of place in joint 'Spine'", 10),
    ("no channels", SMALL.replace("CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation", "CHANNELS 0")
     .replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 0"), "the hierarchy has no CHANNELS", 2),
    ("no Frames", _edit("Frames: 2\n", ""), "expected 'Frames: N' after MOTION, found 'Frame Time: 0.0333333'", 17),
    ("Frames not a number", _edit("Frames: 2", "Frames: two"), "Frames: 'two' is not a whole number", 17),
    ("Frames: 0", _edit("Frames: 2", "Frames: 0"), "Frames: 0, the clip has no frames", 17),
    ("no Frame Time", _edit("Frame Time: 0.0333333\n", ""), "expected 'Frame Time: SECONDS', found '0 90 0 0 0 0 0 0 0'", 18),
    ("zero Frame Time", _edit("Frame Time: 0.0333333", "Frame Time: 0"), "Frame Time must be positive", 18),
    ("negative Frame Time", _edit("Frame Time: 0.0333333", "Frame Time: -0.01"), "Frame Time must be positive", 18),
    ("NaN Frame Time", _edit("Frame Time: 0.0333333", "Frame Time: nan"), "Frame Time: 'nan' is not a number", 18),
    ("short frame line", _edit(FRAME_LINE, "0 90 0 10 0 0 0 0\n"),
     "8 values on this frame line, expected 9 (one per channel of the hierarchy)", 20),
    ("extra values", _edit(FRAME_LINE, "0 90 0 10 0 0 0 0 0 0\n"), "10 values on this frame line, expected 9", 20),
    ("truncated frames", _edit(FRAME_LINE, ""), "truncated: the file has 1 of the 2 frames that 'Frames:' announces", 19),
    ("extra frame lines", SMALL + FRAME_LINE, "3 frame lines, but 'Frames:' says 2", 21),
    ("cut mid-line", SMALL[:-10], "truncated last frame: 4 of 9 values; the file ends mid-line", 20),
    ("blank line", _edit(FRAME_LINE, "\n" + FRAME_LINE), "blank line inside the frame data", 20),
    ("non-numeric", _edit(FRAME_LINE, "0 90 0 10 0 0 0 abc 0\n"), "'abc' is not a number (Xrotation of 'Spine')", 20),
    ("nan", _edit(FRAME_LINE, "0 90 0 10 0 0 0 nan 0\n"), "'nan' is not a number (Xrotation of 'Spine')", 20),
    ("inf", _edit(FRAME_LINE, "0 90 0 10 -inf 0 0 0 0\n"), "'-inf' is not a number (Xrotation of 'Hips')", 20),
    ("overflow", _edit(FRAME_LINE, "0 90 0 10 0 0 0 1e999 0\n"),
     "value 1e999 of Xrotation of 'Spine' is not finite or beyond +-1e+09", 20),
    ("unicode digits", _edit(FRAME_LINE, "0 90 0 10 0 0 0 \u0661 0\n"), "is not a number (Xrotation of 'Spine')", 20),
]  # fmt: skip


@pytest.mark.parametrize("text,message,line", [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED])
def test_every_malformed_file_names_what_where_and_how(text, message, line):
    with pytest.raises(BVHError) as exc:
        parse_bvh_text(text, "clip.bvh", units="cm", up="y")
    e = exc.value
    assert message in e.message, e.message
    assert (e.path, e.line) == ("clip.bvh", line), str(e)
    assert e.fix and str(e).startswith(f"clip.bvh:{line}") and "fix:" in str(e)


def test_kinds_of_malformed_files_are_many():
    assert len(MALFORMED) >= 30


def test_line_ends_and_a_byte_order_mark_are_accepted():
    crlf = ("\ufeff" + SMALL).replace("\n", "\r\n").encode("utf-8")
    a = parse_bvh_bytes(crlf, "a.bvh", units="cm", up="y")
    b = parse_bvh_text(SMALL, "b.bvh", units="cm", up="y")
    np.testing.assert_array_equal(a.values, b.values)
    tabs = SMALL.replace("  ", "\t").replace("Frames: 2", "FRAMES:\t2").replace(" 90 ", "  +90.0e0\t")
    np.testing.assert_array_equal(parse_bvh_text(tabs, units="cm", up="y").values, b.values)


COMPACT = """hierarchy
ROOT Bip01 Pelvis {
OFFSET 0 0 0
CHANNELS 3 Yrotation Xrotation Zrotation
JOINT Bip01 Spine {
OFFSET 0 0 10
}
JOINT Spine_End {
OFFSET 0 0 5
CHANNELS 1 Xposition
End Site { OFFSET 1 2 3 }
}
}
Motion
Frames:1
Frame   Time:  .5
90 0 0 7
"""


def test_names_with_spaces_compact_layout_and_rotation_only_root():
    m = parse_bvh_text(COMPACT, units="m", up="z", facing="keep")
    assert m.joint_names == ("Bip01 Pelvis", "Bip01 Spine", "Spine_End", "Spine_End_End")  # the End Site's name is free
    assert [j.channels for j in m.joints] == [("Yrotation", "Xrotation", "Zrotation"), (), ("Xposition",), ()]
    assert m.fps == 2.0 and m.first_data_line == 17
    # the root turns 90 degrees about y: z offsets go along +x; Spine_End's x comes from its channel (7)
    np.testing.assert_allclose(m.positions()[0], [[0, 0, 0], [10, 0, 0], [5, 0, -7], [8, 2, -8]], atol=1e-12)


@pytest.mark.parametrize(
    "data,message",
    [(b"\xff\xfeH\x00I\x00", "UTF-16 text or binary"), (b"HIERARCHY\nROOT H\xe9\n", "not UTF-8 text (byte 0xe9")],
)
def test_binary_and_foreign_encodings_are_refused(data, message):
    with pytest.raises(BVHError, match=message.replace("(", r"\(")):
        parse_bvh_bytes(data, "x.bvh")


def test_options_are_checked():
    for kw in ({"units": "km"}, {"up": "x"}, {"facing": "north"}):
        with pytest.raises(BVHError, match="is not one of"):
            parse_bvh_text(SMALL, **kw)


# ---- limits -----------------------------------------------------------------------------------


def test_file_size_limit(tmp_path, monkeypatch):
    f = tmp_path / "a.bvh"
    f.write_text(SMALL)
    monkeypatch.setenv("MER_MAX_BVH_BYTES", "100")
    with pytest.raises(BVHError, match="size of a BVH motion capture file is 320 bytes, over mer's limit of 100"):
        read_bvh(f)
    monkeypatch.setenv("MER_MAX_BVH_BYTES", str(len(SMALL)))
    assert read_bvh(f, units="cm").num_frames == 2


@pytest.mark.parametrize(
    "name,value,message,line",
    [
        ("MER_MAX_BVH_LINE_BYTES", "40", "length of one line of a BVH file is 72 bytes", 5),
        ("MER_MAX_BVH_JOINTS", "2", "number of joints (and End Sites) in a BVH hierarchy is over 2 joints", 10),
        ("MER_MAX_BVH_FRAMES", "1", "number of frames of a BVH motion is 2 frames, over mer's limit of 1", 17),
    ],
)
def test_size_limits_name_the_line_and_the_variable(monkeypatch, name, value, message, line):
    monkeypatch.setenv(name, value)
    with pytest.raises(BVHError) as exc:
        parse_bvh_text(SMALL, "a.bvh", units="cm")
    assert message in exc.value.message and exc.value.line == line and name in exc.value.fix


def test_not_a_regular_file(tmp_path):
    with pytest.raises(BVHError, match="is a directory"):
        read_bvh(tmp_path)
    with pytest.raises(BVHError, match="file not found"):
        read_bvh(tmp_path / "nope.bvh")


# ---- names, frame rates, units, up axis, facing ------------------------------------------------


@pytest.mark.parametrize(
    "name,side,core",
    [
        ("LeftUpLeg", "left", "upleg"), ("RightForeArm", "right", "forearm"), ("mixamorig:LeftToeBase", "left", "toebase"),
        ("UpperLeg_L", "left", "upperleg"), ("Toes_R", "right", "toes"), ("L_Hip", "left", "hip"),
        ("r_wrist", "right", "wrist"), ("lfemur", "left", "femur"), ("rhumerus", "right", "humerus"),
        ("Bip01 L Thigh", "left", "thigh"), ("Character1_RightHand", "right", "hand"), ("LHip", "left", "hip"),
        ("hand.L", "left", "hand"), ("ArmRight", "right", "arm"), ("leftArm", "left", "arm"),
        ("Hips", None, "hips"), ("LowerArm", None, "lowerarm"), ("Leftover", None, "leftover"),
        ("Upright", None, "upright"), ("Leg", None, "leg"), ("joint_Root", None, "jointroot"),
    ],
)  # fmt: skip
def test_joint_names_split_into_side_and_core(name, side, core):
    assert split_joint_name(name) == (side, core)


@pytest.mark.parametrize("frame_time,fps", [("0.0333333", 30.0), ("0.00833333", 120.0), ("0.04", 25.0),
                                            ("0.0166667", 60.0), ("0.03", 1 / 0.03)])  # fmt: skip
def test_frame_rate_from_frame_time(frame_time, fps):
    m = parse_bvh_text(SMALL.replace("0.0333333", frame_time), units="cm")
    assert m.fps == pytest.approx(fps, rel=1e-12)


@pytest.mark.parametrize("units", ["m", "cm", "mm", "in"])
@pytest.mark.parametrize("up", ["y", "z"])
def test_units_and_up_axis_are_detected(units, up):
    fig = human_definition(np.random.default_rng(3), 12)
    m = parse_bvh_text(write_bvh(fig, up=up, units=units), facing="keep")
    assert (m.units, m.up) == (units, up), m.notes
    np.testing.assert_allclose(m.positions(), canonical_fk(fig), atol=1e-6)


def test_overrides_win_over_detection():
    fig = human_definition(np.random.default_rng(4), 6)
    text = write_bvh(fig, up="y", units="cm")
    m = parse_bvh_text(text, units="mm", up="z", facing="keep")
    assert (m.units, m.up, m.yaw, m.notes) == ("mm", "z", 0.0, ())
    np.testing.assert_allclose(m.positions(), canonical_fk(fig) @ FILE_FROM_MER["y"].T * 0.1, atol=1e-6)


def test_up_axis_without_head_or_feet_names():
    fig = human_definition(np.random.default_rng(5), 6)
    fig.names = [f"j{k}" for k in range(len(fig.names))]
    for up in ("y", "z"):
        m = parse_bvh_text(write_bvh(fig, up=up, units="m"), facing="keep")
        assert m.up == up and "no head/foot names" in m.notes[0]
        assert m.yaw == 0.0


@pytest.mark.parametrize("heading", [0.0, 90.0, -135.0, 180.0])
def test_facing_turns_the_first_frame_to_face_x(heading):
    fig = human_definition(np.random.default_rng(6), 8, yaw=0.0)
    turn = Rotation.from_euler("z", heading, degrees=True).as_matrix()
    fig.local[:, 0] = turn @ fig.local[:, 0]
    fig.root_pos = fig.root_pos @ turn.T
    m = parse_bvh_text(write_bvh(fig, up="y", units="cm"))
    pos = m.positions()
    left = pos[0, m.index("LeftUpLeg")] - pos[0, m.index("RightUpLeg")]
    assert left[1] > 0 and abs(left[0]) < 0.25 * left[1]
    toe = pos[0, m.index("LeftToe")] - pos[0, m.index("LeftFoot")]
    assert toe[0] > 0  # the feet point forward: +x
    # a rigid turn about z of the figure as the file has it
    kept = parse_bvh_text(write_bvh(fig, up="y", units="cm"), facing="keep").positions()
    R = Rotation.from_euler("z", m.yaw).as_matrix()
    np.testing.assert_allclose(pos, kept @ R.T, atol=1e-9)


# ---- the round trip ---------------------------------------------------------------------------

CONVENTIONS = st.fixed_dictionaries({
    "order": st.sampled_from(["ZXY", "ZYX", "XYZ", "YXZ"]),
    "six": st.booleans(),
    "frame": st.sampled_from([("y", "cm"), ("z", "m"), ("y", "in"), ("z", "mm")]),
    "fps": st.sampled_from([30.0, 120.0]),
    "root_order": st.sampled_from([None, "ZYX", "XYZ"]),
    "detect": st.booleans(),
})  # fmt: skip


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(seed=st.integers(0, 2**32 - 1), conv=CONVENTIONS, spine=st.integers(1, 3), toe=st.booleans())
def test_round_trip_through_conventions_matches_an_independent_fk(seed, conv, spine, toe):
    fig = human_definition(np.random.default_rng(seed), 10, spine=spine, toe=toe)
    up, units = conv["frame"]
    text = write_bvh(fig, order=conv["order"], six=conv["six"], up=up, units=units, fps=conv["fps"],
                     root_order=conv["root_order"])  # fmt: skip
    kw = {} if conv["detect"] else {"units": units, "up": up}
    m = parse_bvh_text(text, "rt.bvh", facing="keep", **kw)
    assert (m.units, m.up, m.fps) == (units, up, conv["fps"])
    pos, rot = canonical_fk(fig, rotations=True)
    np.testing.assert_allclose(m.positions(), pos, atol=1e-6)
    # a joint frame's orientation maps file-axis vectors to the world: the figure's rotation after the axes change
    np.testing.assert_allclose(m.rotations() @ FILE_FROM_MER[up], rot, atol=1e-9)


# ---- real clips -------------------------------------------------------------------------------


@pytest.mark.slow
def test_every_bandai_clip_reads_in_centimetres_y_up_at_30_hz(bandai):
    assert len(bandai) == 174
    for f in bandai:
        m = read_bvh(f)
        assert (m.units, m.up, m.fps) == ("cm", "y", 30.0), (f.name, m.notes)
        assert len(m.joints) == 27 and m.values.shape[1] == 22 * 6
        pos = m.positions()
        feet = pos[:, [m.index(n) for n in ("Foot_L", "Foot_R", "Toes_L", "Toes_R")], 2]
        assert -0.02 < feet.min() < 0.06, (f.name, feet.min())  # the toe joints sit 2.5-4.5 cm above the floor
        head = pos[:, m.index("Head"), 2] - feet.min(1)
        assert 1.15 < np.percentile(head, 95) < 1.6, f.name  # the head joint (skull base; its End Site is at 0)


def test_a_bandai_performer_is_adult_sized(bandai):
    m = read_bvh(next(f for f in bandai if "walk_normal" in f.name))
    pos = m.positions()
    head = pos[:, m.index("Head"), 2] - pos[:, [m.index("Toes_L"), m.index("Toes_R")], 2].min(1)
    stature = head.max() / 0.9  # the skull base is at about 0.9 of the stature (between chin 0.87 and top 1.0)
    assert 1.4 < stature < 2.0


def test_a_bandai_clip_starts_facing_x(bandai):
    m = read_bvh(next(f for f in bandai if "walk_normal" in f.name))
    p = m.positions()
    assert p[0, m.index("UpperLeg_L"), 1] > p[0, m.index("UpperLeg_R"), 1]
    step = p[-1, m.index("Hips")] - p[0, m.index("Hips")]
    assert step[0] > 2.0 and abs(step[1]) < 0.5 * step[0]  # a forward walk goes along +x


def test_only_mer_errors_come_out(bandai):
    text = bandai[0].read_text()
    for cut in (100, 2000, len(text) // 2, len(text) - 30):
        with pytest.raises(MerError):
            parse_bvh_text(text[:cut])
    assert parse_bvh_text(text).num_frames == parse_bvh_text(text + "\n\n").num_frames
