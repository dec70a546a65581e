"""Pydantic models of the environment's configuration files.

Three kinds of file live in ``regimes/``:

* the food catalog (``foods.toml``): named foods with a portion and its nutrients, and the
  daily target in grams;
* the reward config (``reward.toml``): horizon and reward coefficients, the same for every
  regime;
* one file per delay regime (``run0.toml`` .. ``run6.toml``): the Table 1 ranges, the seed
  they were drawn with, and the drawn per-food, per-nutrient mean delay ``tau`` and spread
  ``sigma`` written out, so that the file alone fixes the dynamics.

Every model forbids unknown keys and has no defaults for anything that changes the
dynamics: a missing value is an error, never silently filled in. The only defaults, a
regime's observation options ``observe_clock``, ``observe_pending`` and ``observe_latent``
(all ``false``: the paper's observation), change what the agent observes, not the dynamics.
They climb the observation ladder one rung each (:attr:`Regime.observation_level`): level 1
the paper's observation, 2 + the clock, 3 + the pending amount per nutrient, 4 + the pending
schedule and the target (the full state); a rung needs the ones below it.
"""

from __future__ import annotations

from collections import Counter
from itertools import pairwise, product
from typing import Annotated

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, Strict, field_validator, model_validator

from nutribench.config.sizes import MAX_FOODS, STEPS_BOUND

#: Order of the nutrients in every array of the package.
NUTRIENTS: tuple[str, str, str] = ("C", "F", "P")


def _not_a_bool(value: object) -> object:
    if isinstance(value, bool):
        raise ValueError("true or false is no number: write the number")
    return value


#: Numbers are strict about booleans: pydantic's lax mode read ``learning_rate = true`` as 1.0.
#: (A number written as text stays readable: the stored bodies hold ``"inf"`` for infinity.)
NoBool = BeforeValidator(_not_a_bool)
#: Switches are strict: ``observe_clock = 1`` is no boolean.
StrictBool = Annotated[bool, Strict()]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False), NoBool]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False), NoBool]
#: a config's version: from 1 to what a database integer holds (the versions are stored in columns)
Version = Annotated[int, Field(ge=1, le=2**31 - 1), NoBool]
Key = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$")]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class NonNegNutrients(_Strict):
    """One non-negative number per nutrient (carbohydrate C, fat F, protein P)."""

    C: NonNeg
    F: NonNeg
    P: NonNeg

    def as_array(self) -> np.ndarray:
        return np.array([self.C, self.F, self.P], dtype=np.float64)


class PositiveNutrients(NonNegNutrients):
    C: Positive
    F: Positive
    P: Positive


class Food(_Strict):
    """A food item: one portion of a real food, with its nutrients per 100 g."""

    key: Key
    name: str
    portion: str
    portion_g: Positive
    per_100g: NonNegNutrients
    source_id: str = Field(description="identifier of the entry in the public nutrient table")

    def grams(self) -> np.ndarray:
        """Grams of (C, F, P) in one portion."""
        return self.per_100g.as_array() * self.portion_g / 100.0


class FoodCatalog(_Strict):
    """The foods on offer and the daily target they are measured against."""

    name: str
    version: Version
    source: str
    target_grams: PositiveNutrients
    food: Annotated[
        list[Food],
        Field(
            min_length=1,
            max_length=MAX_FOODS,
            description="the foods; at most MAX_FOODS (nutribench.config.sizes: their dynamics within memory)",
        ),
    ]

    @field_validator("food")
    @classmethod
    def _unique_keys(cls, foods: list[Food]) -> list[Food]:
        counts = Counter(f.key for f in foods)  # linear: 10^5 foods once took minutes here
        dupes = sorted(k for k, n in counts.items() if n > 1)
        if dupes:
            raise ValueError(f"duplicate food keys {dupes}")
        return foods

    @property
    def keys(self) -> list[str]:
        return [f.key for f in self.food]

    def masses(self) -> np.ndarray:
        """(N, 3) nutrients per portion in units of the daily target."""
        grams = np.stack([f.grams() for f in self.food])
        return grams / self.target_grams.as_array()


class RewardConfig(_Strict):
    """Horizon and reward coefficients, shared by every regime (docs: the environment).

    r_t = lp (d_{t-1} - d_t) - lc tanh(d_t / tau_c) - lo tanh(|max(0, s_t - T)|_2^2),
    with d_t = |s_t - T|_1 and nutrients in units of the daily target (T = (1, 1, 1)).
    """

    name: str
    version: Version
    horizon: Annotated[
        int,
        Field(ge=1, description="steps of a day; a step number is stored in an INTEGER column"),
        STEPS_BOUND,
        NoBool,
    ]
    lp: NonNeg
    lc: NonNeg
    lo: Positive
    tau_c: Positive


class Range(_Strict):
    """A closed interval [low, high] of non-negative values."""

    low: NonNeg
    high: NonNeg

    @model_validator(mode="after")
    def _ordered(self) -> Range:
        if self.high < self.low:
            raise ValueError(f"high ({self.high}) is below low ({self.low})")
        return self


class NutrientRanges(_Strict):
    C: Range
    F: Range
    P: Range

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        ranges = (self.C, self.F, self.P)
        return np.array([r.low for r in ranges]), np.array([r.high for r in ranges])


class DelayRanges(_Strict):
    """The Table 1 ranges the per-food delays are drawn from (in steps)."""

    tau: NutrientRanges
    sigma: NutrientRanges


class FoodDelay(_Strict):
    """Mean delay tau and spread sigma (steps) of each nutrient of one food."""

    tau: NonNegNutrients
    sigma: NonNegNutrients


class Regime(_Strict):
    """A delay regime: the ranges, the seed, and the drawn delays written out."""

    name: Key
    version: Version
    description: str
    seed: Annotated[int, Field(ge=0), NoBool]
    catalog: str = Field(description="food catalog file, relative to this file")
    reward: str = Field(description="reward config file, relative to this file")
    ranges: DelayRanges
    foods: Annotated[dict[Key, FoodDelay], Field(max_length=MAX_FOODS)]
    observe_clock: StrictBool = Field(
        default=False,
        description="append the step of the day / horizon to the observation (one more dimension)",
    )
    observe_pending: StrictBool = Field(
        default=False,
        description="also append what is eaten but not yet absorbed, per nutrient (3 dims; needs observe_clock)",
    )
    observe_latent: StrictBool = Field(
        default=False,
        description="also append the pending schedule of the next H - 1 steps and the target (needs observe_pending)",
    )

    @property
    def observation_level(self) -> int:
        """The rung of the observation ladder: 1 (the paper's) .. 4 (the full state)."""
        return 1 + int(self.observe_clock) + int(self.observe_pending) + int(self.observe_latent)

    @model_validator(mode="after")
    def _a_ladder(self) -> Regime:
        for lower, upper in pairwise(("observe_clock", "observe_pending", "observe_latent")):
            if getattr(self, upper) and not getattr(self, lower):
                raise ValueError(
                    f"{upper} = true needs {lower} = true: the observation levels are a ladder "
                    "(clock, then pending, then latent); set the rungs below it too"
                )
        return self

    @model_validator(mode="after")
    def _within_ranges(self) -> Regime:
        for (key, delay), what, n in product(self.foods.items(), ("tau", "sigma"), NUTRIENTS):
            x, r = getattr(getattr(delay, what), n), getattr(getattr(self.ranges, what), n)
            if not r.low - 1e-9 <= x <= r.high + 1e-9:
                raise ValueError(f"foods.{key}.{what}.{n} = {x} is outside ranges.{what}.{n} [{r.low}, {r.high}]")
        return self
