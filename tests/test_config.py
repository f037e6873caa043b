"""Configs that generate their learners (k_s_values, seeds_per_k_s, first_seed, learners)."""

from pathlib import Path

import pytest

from mjxcpg.training import config

# The shipped configs as they were written before they could generate their learners: every
# k_s and every seed spelled out.
SPELLED_OUT = Path(__file__).parent / "data" / "spelled_out"


@pytest.mark.parametrize("name", ["stats", "wide"])
def test_generated_learners_equal_the_lists_spelled_out(name):
    assert config.load_spec(name) == config.load_spec(str(SPELLED_OUT / f"{name}.toml"))


def test_stats_is_ten_seeds_per_k_s_from_seed_100():
    spec = config.load_spec("stats")
    assert spec.k_s[:11] == (0.0,) * 10 + (1.0,)
    assert spec.seeds == tuple(range(100, 170))


def test_expansion_repeats_each_value_then_cycles_to_the_count():
    data = config.expand_learners({"k_s_values": [1.0, 2.0], "seeds_per_k_s": 2, "first_seed": 5,
                                   "learners": 6, "chunk_seconds": 4.0})
    assert data == {"k_s": [1.0, 1.0, 2.0, 2.0, 1.0, 1.0], "seeds": [5, 6, 7, 8, 9, 10], "chunk_seconds": 4.0}


def test_energy_gains_repeat_the_learners_with_the_same_seeds():
    data = config.expand_learners({"k_s_values": [1.0, 2.0], "first_seed": 5, "k_e_values": [0.0, 3.0]})
    assert data == {"k_s": [1.0, 2.0, 1.0, 2.0], "seeds": [5, 6, 5, 6], "k_e": [0.0, 0.0, 3.0, 3.0]}


def test_the_energy_config_puts_each_k_e_beside_the_same_seeds_at_k_e_0():
    spec = config.load_spec("energy")
    cells = {}
    for k_s, seed, k_e in zip(spec.k_s, spec.seeds, spec.k_e):
        cells.setdefault(k_e, set()).add((k_s, seed))
    assert set(cells) == {0.0, 1.0, 4.0} and len(cells[0.0]) == 30
    assert cells[1.0] == cells[0.0] == cells[4.0]
    assert {k for k, _ in cells[0.0]} == {2.0, 5.0, 10.0}


def test_spelled_out_learners_pass_through():
    data = {"k_s": [1.0], "seeds": [3]}
    assert config.expand_learners(data) is data


@pytest.mark.parametrize("text, key", [
    ("k_s_values = [1.0]\nk_s = [1.0]\n", "k_s"),
    ("k_s_values = [1.0]\nseeds = [1]\n", "seeds"),
    ("seeds_per_k_s = 3\n", "seeds_per_k_s"),
    ("k_s_values = []\n", "k_s_values"),
    ("k_s_values = ['fast']\n", r"k_s_values\[0\]"),
    ("k_s_values = [1.0]\nseeds_per_k_s = 0\n", "seeds_per_k_s"),
    ("k_s_values = [1.0]\nfirst_seed = -1\n", "first_seed"),
    ("k_s_values = [1.0]\nlearners = 2.5\n", "learners"),
    ("k_s_values = [1.0]\nk_e_values = [-1.0]\n", r"k_e_values\[0\]"),
    ("k_s_values = [1.0]\nk_e_values = []\n", "k_e_values"),
    ("k_s_values = [1.0]\nk_e = [1.0]\n", "k_e"),
    ("k_s = [1.0, 2.0]\nseeds = [1, 2]\nk_e = [1.0]\n", "k_e"),
    ("k_s = [1.0]\nseeds = [1]\nk_e = [-0.5]\n", r"k_e\[0\]"),
    ("k_s = [1.0]\nseeds = [1]\n[learner]\nstepping_a_max = -0.4\n", r"learner.stepping_a_max"),
])
def test_bad_generator_names_the_key(tmp_path, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"^{key}"):
        config.load_spec(str(path))


def write(tmp_path, text: str) -> str:
    path = tmp_path / "config.toml"
    path.write_text(text)
    return str(path)


def test_platform_key_starts_from_that_robots_gait_and_the_config_changes_it(tmp_path):
    """The child's leg is twice QRIO's: lengths x 2 and times x sqrt(2) by hand, from QRIO's
    published constants; a key of the config's own tables wins over the platform's value."""
    spec = config.load_spec(write(tmp_path, 'platform = "child"\nk_s = [1.0]\nseeds = [0]\n'
                                            '[controller]\nh_vsr = 0.5\n[trial]\nmax_trials = 7\n'))
    assert spec.platform == "child"
    assert spec.controller.z0 == pytest.approx(2 * 0.215) and spec.controller.amp_x == pytest.approx(2 * 0.015)
    assert spec.controller.cpg.tau == pytest.approx(2 ** 0.5 * 0.105)
    assert spec.controller.hand_gain == pytest.approx(2 ** 0.5)
    assert spec.trial.h_ref == pytest.approx(2 * 0.272)
    assert spec.controller.h_vsr == 0.5 and spec.trial.max_trials == 7
    qrio = config.load_spec(write(tmp_path, 'k_s = [1.0]\nseeds = [0]\n'))
    assert qrio.platform == "qrio" and qrio.controller.z0 == 0.215 and qrio.trial.h_ref == 0.272
    assert config.load_spec("child").platform == "child"
    assert config.load_spec("quick", platform="child") == config.load_spec(
        write(tmp_path, 'platform = "child"\n' + (config.CONFIG_DIR / "quick.toml").read_text()))


@pytest.mark.parametrize("text, message", [
    ('platform = "atlas"\nk_s = [1.0]\nseeds = [0]\n', "platform: unknown 'atlas'; choose one of qrio, child"),
    ('platform = 3\nk_s = [1.0]\nseeds = [0]\n', "platform"),
])
def test_bad_platform_is_a_one_line_error_naming_the_key(tmp_path, text, message):
    with pytest.raises(ValueError, match=f"^{message}"):
        config.load_spec(write(tmp_path, text))
