"""Tool library: the shipped file loads, its cutting data are sane, and bad files name the field."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import yaml

from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.model import DEFAULT_HOLDER, HolderSegment, Tool
from cadcam.tools import load_tool_library
from factory.core.errors import ToolError
from factory.core.resources import FIXTURES


@pytest.fixture(scope="module")
def lib():
    return load_tool_library()


@pytest.fixture()
def doc():
    return yaml.safe_load((FIXTURES / "tools.yaml").read_text())


def write(tmp_path: Path, doc) -> Path:
    path = tmp_path / "tools.yaml"
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc, sort_keys=False))
    return path


def test_default_library_has_the_shop_tools(lib):
    assert lib.source == str(FIXTURES / "tools.yaml")
    assert [t.number for t in lib.tools] == list(range(1, 18))
    assert (lib.tool(1).shape, lib.tool(1).diameter, lib.tool(1).flutes) == ("flat", 6, 3)
    assert (lib.tool(3).shape, lib.tool(3).corner_radius) == ("ball", 3)
    assert (lib.tool(5).shape, lib.tool(5).corner_radius) == ("bull", 1)
    for t in lib.tools:
        assert isinstance(t, Tool)
        # a long-neck end mill has short flutes (about 1.5 D) on its neck
        least = 0.5 if t.is_drill and t.point_angle <= 90 else 1.5 if lib.feed_factor(t) < 1 else 2
        assert t.flute_length >= least * t.diameter
        assert t.length >= t.flute_length
    assert [t.diameter for t in lib.drills("aluminium")] == [3.3, 4.2, 5, 6.8, 8.5, 10]
    assert [(t.diameter, t.point_angle) for t in lib.spot_drills("aluminium")] == [(10, 90)]
    assert {"aluminium", "steel", "brass", "plastic"} <= {m.name for m in lib.materials}


def test_long_reach_tools_run_at_their_feed_factor(lib, tmp_path):
    """The long-reach end mills of the default library: 12 mm at 66 mm, 8 mm at 50 mm, a necked 6 mm ball at
    50 mm, each slower than its diameter's feed; a factor outside (0, 1] is named in one line."""
    reach = {t.number: (t.diameter, t.length, t.shape) for t in lib.tools if lib.feed_factor(t) < 1}
    assert reach == {15: (12, 66, "flat"), 16: (8, 50, "flat"), 17: (6, 50, "ball")}
    for n in reach:
        t = lib.tool(n)
        assert t.shank_diameter < t.diameter  # the neck clears the wall the flutes cut
        # the deeper the reach in diameters, the slower
    assert lib.feed_factor(lib.tool(15)) > lib.feed_factor(lib.tool(16)) > lib.feed_factor(lib.tool(17))
    assert lib.feed_factor(lib.tool(2)) == 1.0
    doc = yaml.safe_load((FIXTURES / "tools.yaml").read_text())
    doc["tools"][0]["feed_factor"] = 1.5
    with pytest.raises(ToolError, match=r"tools\[0\]\.feed_factor: must be in \(0, 1\], got 1.5"):
        load_tool_library(write(tmp_path, doc))


def test_missing_tool_lists_the_ones_there_are(lib):
    with pytest.raises(ToolError, match=r"no tool T99 .*T1, T2"):
        lib.tool(99)


@pytest.mark.parametrize("material", ["aluminium", "aluminum", "steel", "brass", "plastic", "POM", "stainless"])
def test_cutting_data_are_sane_for_every_tool(lib, material):
    for t in lib.tools:
        cd = lib.cutting_data(t, material)
        assert 0 < cd.spindle_rpm <= lib.max_rpm
        if t.is_drill:
            # A drill feeds only along its axis: n * f, f in carbide drills' range.
            assert 0 < cd.plunge_feed == cd.feed <= lib.max_feed
            assert 0.02 <= cd.feed / cd.spindle_rpm <= 0.4
            assert 0 < lib.peck_depth(t, material) <= 2 * t.diameter
            vc = math.pi * t.diameter * cd.spindle_rpm / 1000
            assert vc <= lib.material(material).drilling.surface_speed * 1.001
            continue
        assert 0 < cd.plunge_feed < cd.feed <= lib.max_feed
        # Chip load actually cut per tooth stays within carbide's plausible range.
        fz = cd.feed / (cd.spindle_rpm * t.flutes)
        assert 0.002 <= fz <= 0.2
        # Surface speed never exceeds the material's (the rpm cap only lowers it).
        vc = math.pi * t.diameter * cd.spindle_rpm / 1000
        assert vc <= lib.material(material).surface_speed * 1.001


def test_aluminium_figures_are_shop_plausible(lib):
    cd = lib.cutting_data(lib.tool(1), "aluminium")  # 6 mm 3FL at Vc 300
    assert cd.spindle_rpm == pytest.approx(1000 * 300 / (math.pi * 6), abs=1)
    assert 1500 <= cd.feed <= 4000
    small = lib.cutting_data(lib.tool(4), "aluminium")  # 3 mm ball wants 31.8k: capped
    assert small.spindle_rpm == lib.max_rpm


def test_feed_is_capped_by_machine(tmp_path, doc):
    doc["machine"]["max_feed"] = 500
    lib = load_tool_library(write(tmp_path, doc))
    for t in lib.tools:
        assert lib.cutting_data(t, "plastic").feed <= 500


def test_chip_load_interpolates_and_clamps(lib):
    al = lib.material("aluminium")
    assert al.chip_load_for(6) == pytest.approx(0.05)
    assert al.chip_load_for(7) == pytest.approx((0.05 + 0.065) / 2)
    assert al.chip_load_for(0.1) == al.chip_load[0][1]
    assert al.chip_load_for(50) == al.chip_load[-1][1]


def test_unknown_material_lists_known_ones(lib):
    with pytest.raises(ToolError, match=r"unknown material 'titanium'.*aluminium.*steel"):
        lib.cutting_data(lib.tool(1), "titanium")


def _set(doc, path, value):
    *head, last = path
    node = doc
    for k in head:
        node = node[k]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value


DELETE = object()


@pytest.mark.parametrize(
    "path, value, expected",
    [
        (("tools", 2, "diameter"), 0, "tools[2].diameter: must be > 0"),
        (("tools", 2, "diameter"), "six", "tools[2].diameter: must be a number"),
        (("tools", 0, "shape"), "taper", "tools[0].shape: unknown shape 'taper'"),
        (("tools", 2, "corner_radius"), 1.0, "tools[2].corner_radius: a ball end mill has corner_radius"),
        (("tools", 0, "corner_radius"), 0.5, "tools[0].corner_radius: a flat end mill"),
        (("tools", 4, "corner_radius"), 4, "tools[4].corner_radius: must be < diameter/2"),
        (("tools", 4, "corner_radius"), DELETE, "tools[4].corner_radius: missing"),
        (("tools", 1, "number"), 1, "tools[1].number: duplicate tool number 1 (also tools[0])"),
        (("tools", 1, "number"), 0, "tools[1].number: must be >= 1"),
        (("tools", 1, "flutes"), 2.5, "tools[1].flutes: must be a whole number"),
        (("tools", 1, "flutes"), True, "tools[1].flutes: must be a whole number"),
        (("tools", 3, "flute_length"), DELETE, "tools[3].flute_length: missing"),
        (("tools", 3, "lenght"), 20, "tools[3].lenght: unknown key (did you mean length?)"),
        (("machine", "max_rmp"), 20000, "machine.max_rmp: unknown key (did you mean max_rpm?)"),
        (("machine", "max_rpm"), -1, "machine.max_rpm: must be > 0"),
        (("machine",), DELETE, "machine: missing"),
        (("materials", "steel", "surface_speed"), DELETE, "materials.steel.surface_speed: missing"),
        (("materials", "steel", "plunge_fraction"), 2, "materials.steel.plunge_fraction: must be in (0, 1]"),
        (("materials", "brass", "chip_load"), "lots", "materials.brass.chip_load: must be a mapping"),
        (("materials", "brass", "chip_load"), {6: 5}, "materials.brass.chip_load: fz 5.0 mm/tooth is implausible"),
        (("materials", "brass", "aliases"), ["pom"], "materials.plastic: name or alias 'pom' also used by brass"),
        (("tools",), [], "tools: must be a non-empty list"),
        (("tools", 0), "T1 6mm", "tools[0]: must be a mapping"),
        (("tools", 0, "holder"), [], "tools[0].holder: must be a non-empty list"),
        (("tools", 0, "holder"), [{"diameter": 20}], "tools[0].holder[0].length: missing"),
        (("tools", 0, "holder"), [{"diameter": 20, "length": -1}], "tools[0].holder[0].length: must be > 0"),
        (("tools", 1, "holder"), [{"diameter": 20, "length": 5, "top_diameter": 0}],
         "tools[1].holder[0].top_diameter: must be > 0"),
        (("tools", 1, "holder"), [{"diameter": 20, "lenght": 5}], "tools[1].holder[0].lenght: unknown key (did you mean length?)"),
        (("tools", 2, "shank_diameter"), 0, "tools[2].shank_diameter: must be > 0"),
    ],
)
def test_malformed_library_names_the_field(tmp_path, doc, path, value, expected):
    _set(doc, path, value)
    p = write(tmp_path, doc)
    with pytest.raises(ToolError) as info:
        load_tool_library(p)
    err = info.value
    assert err.source == str(p)
    assert expected in err.message, err.message


def test_single_chip_load_value_is_accepted(tmp_path, doc):
    doc["materials"]["plastic"]["chip_load"] = 0.05
    lib = load_tool_library(write(tmp_path, doc))
    assert lib.material("pom").chip_load_for(3) == 0.05


def test_ball_corner_radius_may_be_omitted_and_flat_defaults_to_zero(doc, tmp_path):
    assert "corner_radius" not in doc["tools"][2]  # shipped file relies on the default
    lib = load_tool_library(write(tmp_path, doc))
    assert lib.tool(3).corner_radius == 3 and lib.tool(1).corner_radius == 0


@pytest.mark.parametrize(
    "text, expected",
    [
        ("", "tool library is empty"),
        ("machine: [1, 2\n", "not valid YAML"),
        ("- a\n- b\n", "must be a mapping"),
        ("machine: {max_rpm: 1, max_feed: 1}\nmaterials: {}\ntools: []\n", "materials: must be a non-empty mapping"),
    ],
)
def test_broken_yaml(tmp_path, text, expected):
    p = write(tmp_path, text)
    with pytest.raises(ToolError) as info:
        load_tool_library(p)
    assert expected in info.value.message
    # A syntax error names the line: ``FILE:LINE``.
    assert info.value.source == (f"{p}:2" if "not valid YAML" in expected else str(p))


def test_missing_file(tmp_path):
    with pytest.raises(ToolError, match="no such tool library"):
        load_tool_library(tmp_path / "nope.yaml")


def test_every_shop_tool_has_its_holder(lib, doc):
    assert all("holder" in t and "shank_diameter" in t for t in doc["tools"])
    t1 = lib.tool(1)
    assert t1.shank_diameter == 6.0
    assert t1.holder == (HolderSegment(22.0, 10.0, 28.0), HolderSegment(32.0, 40.0, 32.0))
    assert lib.tool(4).shank_diameter == 2.8  # the long neck


def test_holder_and_shank_default_when_omitted(tmp_path, doc):
    for t in doc["tools"]:
        del t["holder"], t["shank_diameter"]
    lib = load_tool_library(write(tmp_path, doc))
    assert all(t.holder == DEFAULT_HOLDER and t.shank_diameter == t.diameter for t in lib.tools)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(2.0, 60.0), st.floats(0.5, 40.0), st.floats(2.0, 60.0)), min_size=1, max_size=4),
    st.floats(1.0, 20.0), st.floats(5.0, 40.0), st.floats(0.0, 1.0),
)
def test_body_cylinders_hold_the_true_shank_and_holder(segments, shank, stickout, where):
    """At every height, the stacked cylinders are at least as wide as the shank or holder there."""
    holder = tuple(HolderSegment(d, length, top) for d, length, top in segments)
    tool = Tool(1, "t", "flat", 6.0, 0.0, min(4.0, stickout), 2, stickout, shank_diameter=shank, holder=holder)
    body = tool.body()
    assert [h for h, _ in body] == sorted(h for h, _ in body)
    assert all(r1 > r0 for (_, r0), (_, r1) in zip(body, body[1:]))

    def body_radius(z):
        return max((r for h, r in body if h <= z + 1e-9), default=0.0)

    top = stickout + sum(seg.length for seg in holder)
    z = tool.flute_length + where * (top - tool.flute_length)
    if z < stickout:
        true = shank / 2
    else:
        base = stickout
        true = 0.0
        for seg in holder:
            if z <= base + seg.length:
                u = (z - base) / seg.length
                true = (seg.diameter + (seg.top_diameter - seg.diameter) * u) / 2
                break
            base += seg.length
    assert body_radius(z) >= true - 1e-9


def test_a_drill_needs_its_point_angle_and_only_drills_have_one(tmp_path):
    doc = yaml.safe_load((FIXTURES / "tools.yaml").read_text())
    drill = next(i for i, t in enumerate(doc["tools"]) if t["shape"] == "drill")
    del doc["tools"][drill]["point_angle"]
    with pytest.raises(ToolError, match=rf"tools\[{drill}\]\.point_angle: missing"):
        load_tool_library(write(tmp_path, doc))
    doc = yaml.safe_load((FIXTURES / "tools.yaml").read_text())
    doc["tools"][0]["point_angle"] = 118
    with pytest.raises(ToolError, match=r"tools\[0\]\.point_angle: only drills"):
        load_tool_library(write(tmp_path, doc))
    doc = yaml.safe_load((FIXTURES / "tools.yaml").read_text())
    del doc["materials"]["steel"]["drilling"]
    lib = load_tool_library(write(tmp_path, doc))
    assert lib.drills("steel") == () and lib.drills("aluminium")
    with pytest.raises(ToolError, match=r"no drilling data"):
        lib.cutting_data(lib.drills("aluminium")[0], "steel")


def test_a_drill_round_trips_and_its_point_is_its_profile(lib):
    d = lib.drills("aluminium")[-1]
    assert Tool.from_dict(d.to_dict()) == d
    assert d.point_length == pytest.approx(d.radius / math.tan(math.radians(59)))
    assert float(d.profile_height(d.radius)) == pytest.approx(d.point_length)
    assert float(d.profile_height(d.radius + 0.1)) == math.inf
    spot = lib.spot_drills("aluminium")[0]
    assert spot.point_slope == pytest.approx(1.0)


def test_axial_limit_is_read_and_tools_without_it_take_the_rule(lib, doc, tmp_path):
    """The 2 mm flat and the long-neck tools carry their own full-width depth, 0.5 x D; the others 1 x D (3 mm up)."""
    assert lib.tool(6).axial_limit == 1.0 and lib.tool(6).full_width_limit == 1.0
    assert lib.tool(4).full_width_limit == 1.5
    assert [lib.tool(n).full_width_limit for n in (15, 16, 17)] == [6.0, 4.0, 3.0]
    assert lib.tool(1).axial_limit is None and lib.tool(1).full_width_limit == 6.0
    assert lib.tool(2).full_width_limit == 10.0
    # below 3 mm the rule halves it; never beyond the flutes
    small = Tool(20, "1 mm flat", "flat", 1.0, 0.0, 3.0, 2, 10.0)
    assert small.full_width_limit == 0.5
    stubby = Tool(21, "12 mm flat, short flutes", "flat", 12.0, 0.0, 8.0, 3, 40.0)
    assert stubby.full_width_limit == 8.0
    # a tool table written from the library keeps what the library said, and only that
    d = lib.tool(6).to_dict()
    assert d["axial_limit"] == 1.0 and Tool.from_dict(d) == lib.tool(6)
    assert "axial_limit" not in lib.tool(1).to_dict() and Tool.from_dict(lib.tool(1).to_dict()) == lib.tool(1)
    _set(doc, ["tools", 0, "axial_limit"], 3)
    assert load_tool_library(write(tmp_path, doc)).tool(1).full_width_limit == 3.0


def test_engagement_and_radial_limit_are_read_and_tools_without_them_take_the_rule(lib, doc, tmp_path):
    """The long-neck flat end mills hold 0.1 D and at most 0.2 D below their full-width depth; the others the
    rule's 0.15 D and 0.3 D. A tool table written from the library keeps what the library said, and only that."""
    for n in (15, 16):
        t = lib.tool(n)
        assert (t.engagement, t.radial_limit) == (0.1, 0.2)
        assert t.engagement_target == pytest.approx(0.1 * t.diameter)
        assert t.deep_radial_limit == pytest.approx(0.2 * t.diameter)
        assert Tool.from_dict(t.to_dict()) == t and t.to_dict()["radial_limit"] == 0.2
    t = lib.tool(2)
    assert (t.engagement, t.radial_limit) == (None, None)
    assert (t.engagement_target, t.deep_radial_limit) == (pytest.approx(1.5), pytest.approx(3.0))
    assert "engagement" not in t.to_dict() and "radial_limit" not in t.to_dict()
    _set(doc, ["tools", 1, "engagement"], 0.12)
    assert load_tool_library(write(tmp_path, doc)).tool(2).engagement_target == pytest.approx(1.2)


@pytest.mark.parametrize("key, index, value, expected", [
    ("engagement", 0, 0, "tools[0].engagement: must be > 0, got 0"),
    ("engagement", 0, 0.5, "tools[0].engagement: must be < 0.5 (a share of the diameter), got 0.5"),
    ("radial_limit", 0, 1.5, "tools[0].radial_limit: must be <= 1 (a share of the diameter), got 1.5"),
    ("radial_limit", 0, 0.1, "tools[0].radial_limit: radial_limit 0.1 must be >= engagement 0.15"),
    ("engagement", 0, 0.4, "tools[0].engagement: radial_limit 0.3 must be >= engagement 0.4"),
    ("radial_limit", 7, 0.2, "tools[7].radial_limit: a drill cuts only along its axis"),
])
def test_a_bad_engagement_names_its_field(tmp_path, doc, key, index, value, expected):
    _set(doc, ["tools", index, key], value)
    with pytest.raises(ToolError, match=re.escape(expected)):
        load_tool_library(write(tmp_path, doc))


@pytest.mark.parametrize("index, value, expected", [
    (0, 0, "tools[0].axial_limit: must be > 0, got 0"),
    (0, "deep", "tools[0].axial_limit: must be a number, got 'deep'"),
    (0, 19, "tools[0].axial_limit: must be <= flute_length 18, got 19"),
    (7, 5, "tools[7].axial_limit: a drill cuts only along its axis"),
])
def test_a_bad_axial_limit_names_its_field(tmp_path, doc, index, value, expected):
    _set(doc, ["tools", index, "axial_limit"], value)
    with pytest.raises(ToolError) as e:
        load_tool_library(write(tmp_path, doc))
    assert expected in str(e.value)
