"""scripts/wheel.py's check of the wheel's platform tag, on `auditwheel show` output and wheel names
written here (no wheel is built): the wheel promises manylinux_2_28, so a tag that needs a newer
glibc, or no manylinux tag at all, stops `make wheel` with a message naming the tag."""

import importlib.util

import pytest

from conftest import REPO

spec = importlib.util.spec_from_file_location("wheel_script", REPO / "scripts" / "wheel.py")
wheel = importlib.util.module_from_spec(spec)
spec.loader.exec_module(wheel)


def shown(constrained=None, consistent="manylinux_2_28_x86_64"):
    """`auditwheel show`'s text (auditwheel 6's wording and line wrapping) for a wheel consistent
    with `consistent` whose versioned symbols constrain it to `constrained`, if given."""
    text = (f'\npgser-0.4.0-cp310-abi3-linux_x86_64.whl is consistent with the\nfollowing platform tag: '
            f'"{consistent}".\n\nThe wheel references external versioned symbols in these\n'
            "system-provided shared libraries: libc.so.6 with versions {'GLIBC_2.2.5', 'GLIBC_2.28'}\n")
    if constrained:
        text += (f'\nThis constrains the platform tag to "{constrained}". In order\nto achieve a more '
                 "compatible tag, you would need to recompile a new\nwheel from source on a system with "
                 "earlier versions of these\nlibraries, such as a recent manylinux image.\n")
    return text + "\nThe wheel requires no external shared libraries! :)\n"


@pytest.mark.parametrize("tag", ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux_2_5_x86_64"])
def test_a_tag_up_to_manylinux_2_28_is_taken(tag):
    assert wheel.shown_tag(shown(constrained=tag, consistent=tag)) == tag


def test_without_a_constraint_the_consistent_tag_is_taken():
    assert wheel.shown_tag(shown(consistent="manylinux_2_17_x86_64")) == "manylinux_2_17_x86_64"


@pytest.mark.parametrize("tag, why", [
    ("manylinux_2_31_x86_64", "needs glibc 2.31, newer than manylinux_2_28_x86_64 allows"),
    ("manylinux_3_1_x86_64", "needs glibc 3.1, newer than manylinux_2_28_x86_64 allows"),
    ("linux_x86_64", "'linux_x86_64' is no manylinux tag"),
    ("manylinux_2_28_aarch64", "'manylinux_2_28_aarch64' is no manylinux tag"),
])
def test_a_newer_tag_or_none_is_refused(tag, why):
    with pytest.raises(SystemExit) as e:
        wheel.shown_tag(shown(constrained=tag, consistent=tag))
    msg = str(e.value)
    assert msg.startswith("wheel.py: auditwheel show: platform tag") and why in msg, msg
    assert "\n" not in msg, msg


def test_show_output_without_a_tag_is_refused():
    with pytest.raises(SystemExit) as e:
        wheel.shown_tag("usage: auditwheel show [-h] WHEEL_FILE\n")
    assert "auditwheel show names no platform tag" in str(e.value)


def test_the_repaired_wheels_name_is_checked_tag_by_tag():
    ok = "pgser-0.4.0-cp310-abi3-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
    assert wheel.wheel_tags(ok) == ["manylinux_2_17_x86_64", "manylinux2014_x86_64"]
    assert wheel.wheel_tags("pgser-0.4.0-cp310-abi3-manylinux_2_28_x86_64.whl") == ["manylinux_2_28_x86_64"]
    for bad in ["pgser-0.4.0-cp310-abi3-manylinux_2_28_x86_64.manylinux_2_34_x86_64.whl",
                "pgser-0.4.0-cp310-abi3-linux_x86_64.whl"]:
        with pytest.raises(SystemExit) as e:
            wheel.wheel_tags(bad)
        assert bad in str(e.value), e.value
