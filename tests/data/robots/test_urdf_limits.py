"""URDF input limits (size, element count, depth, line length), encodings, value bounds, linear time."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mer_data.base.errors import MalformedURDFError, UnsafeURDFError
from mer_data.robots.builder import build_skeleton
from mer_data.robots.card import RobotCard
from mer_data.robots.keypoints import propose_keypoints
from mer_data.robots.urdf import load_urdf, parse_urdf_bytes


def chain(n: int, *, origin: str = "0 0 0.01", limit: str = 'lower="-1" upper="1"') -> bytes:
    """An n-link chain of revolute joints."""
    parts = ['<?xml version="1.0"?>\n<robot name="chain">']
    parts += [f'<link name="l{i}"/>' for i in range(n)]
    parts += [
        f'<joint name="j{i}" type="revolute"><parent link="l{i - 1}"/><child link="l{i}"/>'
        f'<origin xyz="{origin}"/><axis xyz="0 1 0"/><limit {limit}/></joint>'
        for i in range(1, n)
    ]
    return ("\n".join(parts) + "\n</robot>\n").encode()


def test_50_mb_urdf_is_refused_up_front_with_the_limit(tmp_path):
    f = tmp_path / "huge.urdf"
    with open(f, "wb") as fh:  # a sparse 50 MB file: refused from its size, never read
        fh.truncate(50 * 2**20)
    t0 = time.perf_counter()
    with pytest.raises(MalformedURDFError) as e:
        load_urdf(f)
    assert time.perf_counter() - t0 < 1.0
    msg = str(e.value)
    assert "52,428,800 bytes" in msg and "33,554,432" in msg and "MER_MAX_URDF_BYTES" in msg and str(f) in msg


def test_size_limit_can_be_raised(monkeypatch):
    data = chain(3)
    monkeypatch.setenv("MER_MAX_URDF_BYTES", "100")
    with pytest.raises(MalformedURDFError, match="MER_MAX_URDF_BYTES"):
        parse_urdf_bytes(data)
    monkeypatch.setenv("MER_MAX_URDF_BYTES", str(len(data)))
    assert len(parse_urdf_bytes(data).joints) == 2


def test_too_many_links_is_refused(monkeypatch):
    monkeypatch.setenv("MER_MAX_URDF_ELEMENTS", "50")
    with pytest.raises(MalformedURDFError) as e:
        parse_urdf_bytes(chain(51), "c.urdf")
    assert "51 elements" in str(e.value) and "MER_MAX_URDF_ELEMENTS" in str(e.value) and "<link>" in str(e.value)


def test_deep_nesting_is_refused():
    body = "<a>" * 80 + "</a>" * 80
    data = f'<robot name="r"><link name="b"/><link name="c">{body}</link></robot>'.encode()
    with pytest.raises(MalformedURDFError, match="MER_MAX_XML_DEPTH") as e:
        parse_urdf_bytes(data, "deep.urdf")
    assert e.value.line == 1


def test_long_line_is_refused_with_its_line(monkeypatch):
    monkeypatch.setenv("MER_MAX_URDF_LINE_BYTES", "1000")
    data = b'<robot name="r">\n<link name="a"/>\n<!--' + b"x" * 2000 + b"-->\n</robot>\n"
    with pytest.raises(MalformedURDFError, match="MER_MAX_URDF_LINE_BYTES") as e:
        parse_urdf_bytes(data, "long.urdf")
    assert e.value.line == 3


@pytest.mark.parametrize("codec", ["utf-16", "utf-16-le", "utf-16-be", "utf-32"])
def test_wide_encodings_do_not_bypass_the_doctype_refusal(codec):
    text = '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a SYSTEM "file:///etc/passwd">]>\n<robot name="r"><link name="&a;"/></robot>'
    with pytest.raises(UnsafeURDFError) as e:
        parse_urdf_bytes(text.encode(codec), "wide.urdf")
    assert e.value.line == 2


def test_utf16_urdf_without_doctype_loads():
    text = '<?xml version="1.0" encoding="UTF-16"?>\n<robot name="r"><link name="a"/><link name="b"/>' + (
        '<joint name="j" type="continuous"><parent link="a"/><child link="b"/></joint></robot>'
    )
    assert parse_urdf_bytes(text.encode("utf-16")).joint_names == ("j",)


@pytest.mark.parametrize(
    "data",
    [
        chain(3, origin="0 0 1e308"),
        chain(3, limit='lower="-1e308" upper="1e308"'),
        chain(3).replace(b'<axis xyz="0 1 0"/>', b'<axis xyz="0 1e308 0"/>', 1),
        chain(3).replace(b'<link name="l0"/>', b'<link name="l0"><collision><geometry><box size="1e308 1 1"/></geometry></collision></link>'),
    ],
    ids=["origin", "limit", "axis", "box"],
)
def test_huge_values_are_refused_not_turned_into_nan(data):
    with pytest.raises(MalformedURDFError, match="beyond"):
        parse_urdf_bytes(data, "big.urdf")


def test_unchecked_elements_fail_as_mer_errors():
    data = chain(3).replace(b'<link name="l0"/>', b'<link name="l0"><inertial><mass value="heavy"/></inertial></link>')
    with pytest.raises(MalformedURDFError):
        parse_urdf_bytes(data, "bad.urdf")


def _card() -> RobotCard:
    return RobotCard(name="chain", urdf="chain.urdf", keypoints={})


def _best_of(fn, n=3) -> float:
    best = float("inf")
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def test_processing_is_linear_in_the_number_of_links():
    """Building the skeleton of a 4x longer chain takes ~4x as long (a joint scan per link: 16x)."""
    small, large = parse_urdf_bytes(chain(1000)), parse_urdf_bytes(chain(4000))
    t_small = _best_of(lambda: build_skeleton(small, _card()))
    t_large = _best_of(lambda: build_skeleton(large, _card()))
    assert t_large / t_small < 9, (t_small, t_large)


def test_a_5000_link_chain_loads_builds_and_proposes_quickly(tmp_path):
    f = tmp_path / "chain.urdf"
    f.write_bytes(chain(5000))
    t0 = time.perf_counter()
    urdf = load_urdf(f)
    skel = build_skeleton(urdf, _card())
    propose_keypoints(urdf, {})
    elapsed = time.perf_counter() - t0
    assert skel.num_nodes == 5000 and np.isfinite(skel.offsets).all()
    assert elapsed < 30, elapsed  # ~2.5 s on 2 busy cores (before the link index: ~9 s, quadratic)
