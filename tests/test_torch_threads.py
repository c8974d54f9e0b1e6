"""torch's CPU threads for a training process (tensegrity_gym.integrations.torch_threads): a bad
thread count is a ValueError naming ``n``, and the command lines' ``--num-threads`` a usage error."""
import argparse

import pytest

from tensegrity_gym.integrations.torch_threads import num_threads_arg, set_torch_threads


@pytest.mark.parametrize("n", [0, -1, True, False, 2.5, float("nan"), "2", None])
def test_set_torch_threads_rejects_a_bad_count(n):
    with pytest.raises(ValueError, match=rf"^n: must be an integer >= 1 \(torch CPU threads\), got {n!r}$"):
        set_torch_threads(n)


def test_set_torch_threads_takes_an_integral_count():
    torch = pytest.importorskip("torch")
    before = torch.get_num_threads()
    try:
        assert set_torch_threads(2.0) == 2 and torch.get_num_threads() == 2
        assert set_torch_threads() == 1 and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("text", ["0", "-2", "2.5", "two", ""])
def test_num_threads_option_rejects_a_bad_count(text):
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be an integer >= 1 \(torch CPU threads\)"):
        num_threads_arg(text)
    assert num_threads_arg("3") == 3


def test_command_lines_give_a_usage_error_for_zero_threads(capsys):
    from tensegrity_gym.integrations.rsl_rl import main      # parses before it imports rsl_rl or torch
    with pytest.raises(SystemExit) as e:
        main(["--num-threads", "0"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "argument --num-threads: must be an integer >= 1 (torch CPU threads), got '0'" in err
    assert "Traceback" not in err
    pytest.importorskip("stable_baselines3")
    from agents import train
    with pytest.raises(SystemExit) as e:
        train.build_parser().parse_args(["--env", "Pendulum-v1", "--num-threads", "0"])
    assert e.value.code == 2 and "argument --num-threads: must be an integer >= 1" in capsys.readouterr().err
