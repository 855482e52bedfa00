"""Bad input to the control commands: an actuator region or a target missing from the Case is
named (before any solve), an unknown actuator in --state-push is named."""
import pytest

from tissue_reference.tissue.cli import main

BOX = """name = "box"
[mesh]
builtin = "box"
size = 5.0
[material]
model = "neo-hookean"
E = 6.0
nu = 0.45
[[boundary]]
region = "zmin"
type = "fixed"
[[actuator]]
name = "A1"
region = "{region}"
direction = [-1.0, 0.0, 0.0]
[[probe]]
name = "T1"
point = [5.0, 5.0, 5.0]
"""


@pytest.fixture
def box_case(tmp_path):
    def make(region):
        p = tmp_path / f"box_{region}.toml"
        p.write_text(BOX.format(region=region))
        return str(p)
    return make


def run(argv, capsys):
    rc = main(argv)
    return rc, capsys.readouterr().err


def test_missing_actuator_region_is_named(box_case, capsys, tmp_path):
    rc, err = run(["mpc", box_case("act_zz"), "--target", "T1", "--task", "1"], capsys)
    assert rc == 2 and "'act_zz'" in err and "zmax" in err     # the regions there are listed
    rc, err = run(["table1", box_case("act_zz"), "--out", str(tmp_path / "t")], capsys)
    assert rc == 2 and "'act_zz'" in err


@pytest.mark.parametrize("cmd", [["mpc", "--target", "T9", "--task", "1"],
                                 ["table1", "--targets", "T1", "T9", "--out", "OUT"]])
def test_missing_target_is_named_before_any_solve(box_case, capsys, tmp_path, cmd):
    argv = [cmd[0], box_case("zmax")] + [str(tmp_path / "t") if c == "OUT" else c for c in cmd[1:]]
    rc, err = run(argv, capsys)
    assert rc == 2 and "'T9'" in err and "T1" in err
    assert not (tmp_path / "t" / "table1.json").exists()


def test_missing_actuator_in_state_push_is_named(box_case, capsys):
    rc, err = run(["jacobian", box_case("zmax"), "--state-push", "A9=1.0"], capsys)
    assert rc == 2 and "'A9'" in err and "A1" in err
