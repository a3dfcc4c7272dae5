"""The seed sets. Reported results use TEST only; nothing is ever tuned or selected on it.

| set    | seeds                       | shape                  | used by                              |
|--------|-----------------------------|------------------------|--------------------------------------|
| test   | 0..999 (0..99: quick subset)| drawn from the seed    | results (ikpd.py, eval.py), archive  |
| eval   | 900000..900014              | 5 per shape, forced    | evaluation during training, sweeps   |
| tune   | 800000..800049              | drawn from the seed    | tuning the analytic lead's tau       |
| pool   | 1000000..1009999            | drawn from the seed    | the self-collision study's subset:   |
|        |                             |                        | where the classical rollout collides |
| train  | 10^7 .. 2^31-1, env i's own | drawn (or restricted)  | training: env i of training seed s   |
|        | stream SeedSequence(s)[i]   |                        | draws from its own spawned stream    |
| distill| 3000000..3099999            | drawn from the seed    | studies/distill.py's teacher data:   |
|        | (training seed k: its own   |                        | the ILC oracle's leads to regress on |
|        | slice of DISTILL_SLICE)     |                        |                                      |
| select | 5000000..5002377            | drawn from the seed    | ranking studies and models           |
|        |                             |                        | (studies/selection.py; issue 37)     |
"""

from __future__ import annotations

from .errors import UserError
from .trajectory import SHAPES

TEST_SEEDS = tuple(range(0, 1000))
QUICK_TEST_SEEDS = TEST_SEEDS[:100]  # the quick subset: archive sidecars and cards report it
EVAL_SHAPES = SHAPES
EVAL_SEEDS_PER_SHAPE = 5
# (seed, forced shape): 900000-900004 circles, 900005-900009 figure-eights, 900010-900014 fly.
EVAL_SET = tuple(
    (900_000 + i * EVAL_SEEDS_PER_SHAPE + j, shape)
    for i, shape in enumerate(EVAL_SHAPES)
    for j in range(EVAL_SEEDS_PER_SHAPE)
)
TUNE_SEEDS = tuple(range(800_000, 800_050))
# More trajectories from the test distribution, for a study that needs a rare subset of them
# (self-collision: about 3% of trajectories). Never trained, tuned or selected on.
POOL_SEEDS = range(1_000_000, 1_010_000)
# Trajectories the distilled student learns from (studies/distill.py): training seed k (1..10)
# draws from its own slice DISTILL_SEEDS[(k - 1) * DISTILL_SLICE : k * DISTILL_SLICE].
DISTILL_SEEDS = range(3_000_000, 3_100_000)
DISTILL_SLICE = 10_000
# The selection set: studies and models are ranked on it (studies/selection.py), sized from the
# measured per-trajectory spread of two close studies' paired differences to show 0.05 cm
# (results/studies/rank/sizing.md). Never trained, tuned or tested on.
SELECT_SIZE = 2378
SELECT_SEEDS = tuple(range(5_000_000, 5_000_000 + SELECT_SIZE))
TRAIN_SEED_LOW, TRAIN_SEED_HIGH = 10_000_000, 2**31 - 1
# One rollout file per seed: a range larger than this is a typo (0-99999999 would be 100M files).
MAX_SEEDS = 100_000
# The largest trajectory seed: seeds are held as int64 (a batch's traj_seeds, numpy's arrays).
MAX_SEED = 2**63 - 1


def set_name(seeds) -> str:
    """Which set these trajectory seeds all belong to, as a table names it: "test",
    "selection", "tuning", "evaluation", "pool", "distillation" or, for a mix or none of them,
    "trajectory"."""
    seeds = list(seeds)
    eval_seeds = {s for s, _ in EVAL_SET}
    for name, members in (("test", TEST_SEEDS), ("selection", SELECT_SEEDS),
                          ("tuning", TUNE_SEEDS), ("evaluation", eval_seeds),
                          ("pool", POOL_SEEDS), ("distillation", DISTILL_SEEDS)):
        if seeds and all(s in members for s in seeds):
            return name
    return "trajectory"


def check_seed(seed: int, flag: str = "--seed") -> int:
    """A trajectory seed must be an integer in 0..MAX_SEED; else UserError naming ``flag``."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise UserError(f"{flag} must be an integer in 0..{MAX_SEED} (2^63-1), got {seed!r}")
    return seed


def parse_seed_range(text: str) -> list[int]:
    """'7' -> [7]; '0-99' -> [0..99]; '1,4,9' and '0-4,10' also work; a seed named twice
    ('0-5,3-8') is played once, in first-named order. Bad ranges, seeds above MAX_SEED, and
    more than MAX_SEEDS seeds in all, raise UserError (before any list is built)."""
    seeds: list[int] = []
    count = 0
    text = str(text).strip()
    if not text:
        raise UserError("empty seed range; use N, A-B or a comma list such as 0-9,20")
    for part in text.split(","):
        part = part.strip()
        lo_s, sep, hi_s = part.partition("-")
        if max(len(lo_s.strip()), len(hi_s.strip())) > len(str(MAX_SEED)):
            raise UserError(f"seed range {part[:40] + '...'!r}: seeds are at most {MAX_SEED} "
                            "(2^63-1)")
        try:
            if not sep:
                lo = hi = int(part)
            else:
                if not lo_s or not hi_s:
                    raise ValueError
                lo, hi = int(lo_s), int(hi_s)
        except ValueError:
            raise UserError(
                f"malformed seed range {part!r}; use N, A-B (e.g. 0-99) or a comma list"
            ) from None
        if lo < 0:
            raise UserError(f"seed range {part!r}: seeds are non-negative integers")
        if hi > MAX_SEED:
            raise UserError(f"seed range {part!r}: seeds are at most {MAX_SEED} (2^63-1)")
        if hi < lo:
            raise UserError(f"seed range {part!r} is empty: {hi} < {lo}")
        count += hi - lo + 1
        if count > MAX_SEEDS:
            raise UserError(f"seed range {text!r} holds more than {MAX_SEEDS:,} seeds (one file "
                            "each); split it into smaller runs")
        seeds.extend(range(lo, hi + 1))
    return list(dict.fromkeys(seeds))  # overlapping parts once: one rollout file per seed
