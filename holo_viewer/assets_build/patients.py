"""Build time: the six patients' recipes and their heads (``scripts/build_patients.py``; docs/patients.md).

Each recipe names the patient (sex, age, Fitzpatrick skin type), a seed, the hair shell
(:class:`.ict.HairStyle`) and the painted look (:class:`.texture_painter.Look`). The identity is
drawn from ICT Face Model Light's identity space: seeded normal coefficients on its first
``N_MODES`` modes (ICT's units: about one standard deviation each), then set along two directions to
read as the patient's sex and age. The directions come from the modes themselves: each is the sum of
the normalised gradients of landmark measures that differ between the sexes (jaw width, brow ridge,
nose width and projection, lower-face height, lip height) or with age (nose length, thinner lips,
lower brows, smaller eye aperture), the age direction made orthogonal to the sex one. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .ict import HAIRLINE, HairStyle
from .texture_painter import Look

__all__ = ["Recipe", "RECIPES", "N_MODES", "identity_directions", "identity_coefficients", "recipe"]

#: ICT identity modes a patient's identity uses (of 100)
N_MODES = 60
#: standard deviation of the random part of the coefficients
RANDOM_SD = 0.7

# landmark measures (relative to the outer-canthal distance) that separate the sexes / ages
_SEX = {"jaw_w": 1.0, "brow_ridge": 1.0, "nose_w": 1.0, "lowface_h": 1.0, "lip_h": -1.0, "nose_proj": 0.5,
        "eye_h": -0.5}
_AGE = {"nose_len": 1.0, "lip_h": -1.0, "browgap": -1.0, "eye_h": -1.0}


def _measures(v: np.ndarray, lm: np.ndarray) -> dict[str, float]:
    p = v[lm]
    eyes = float(np.linalg.norm(p[36] - p[45]))
    return {"jaw_w": np.linalg.norm(p[4] - p[12]) / eyes,
            "brow_ridge": (p[[19, 24], 2].mean() - p[[37, 38, 43, 44], 2].mean()) / eyes,
            "nose_w": np.linalg.norm(p[31] - p[35]) / eyes,
            "lowface_h": (p[33, 1] - p[8, 1]) / eyes,
            "lip_h": (p[51, 1] - p[57, 1]) / eyes,
            "nose_len": (p[27, 1] - p[33, 1]) / eyes,
            "nose_proj": (p[30, 2] - p[33, 2]) / eyes,
            "browgap": (p[19, 1] - p[37, 1]) / eyes,
            "eye_h": (p[37, 1] - p[41, 1]) / eyes}


def identity_directions(neutral: np.ndarray, deltas: np.ndarray, landmarks: np.ndarray,
                        n_modes: int = N_MODES) -> tuple[np.ndarray, np.ndarray]:
    """Unit (n_modes,) directions in coefficient space: male-ward and older-ward (orthogonal)."""
    base = _measures(neutral, landmarks)
    grads = {k: np.zeros(n_modes) for k in base}
    for i in range(n_modes):
        m = _measures(neutral + deltas[i], landmarks)
        for k in base:
            grads[k][i] = m[k] - base[k]

    def direction(weights: dict[str, float]) -> np.ndarray:
        d = sum(w * grads[k] / np.linalg.norm(grads[k]) for k, w in weights.items())
        return d / np.linalg.norm(d)

    sex = direction(_SEX)
    age = direction(_AGE)
    age = age - (age @ sex) * sex
    return sex, age / np.linalg.norm(age)


def identity_coefficients(seed: int, sex_score: float, age_score: float, sex_dir: np.ndarray,
                          age_dir: np.ndarray) -> np.ndarray:
    """Seeded coefficients whose components along the two directions are the given scores."""
    rng = np.random.default_rng(seed)
    c = rng.normal(0.0, RANDOM_SD, len(sex_dir))
    c -= (c @ sex_dir) * sex_dir
    c -= (c @ age_dir) * age_dir
    return c + sex_score * sex_dir + age_score * age_dir


@dataclass(frozen=True)
class Recipe:
    name: str
    sex: str
    age: int
    fitzpatrick: str
    seed: int
    description: str
    hair: HairStyle
    look: Look
    sex_score: float = 0.0
    age_score: float = 0.0
    ipd_mm: float = 63.0
    hair_notes: dict = field(default_factory=dict)
    #: per-AU gains on the shared pain face (``flame.expressions.AUMap.pain_gains``), written into
    #: ``patient.json`` when set (docs/patients.md)
    pain_gains: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------- hair
# a woman's hairline: rounder at the temples, no sideburns
_F_LINE = ((0.0, 31.0), (20.0, 31.0), (40.0, 27.0), (55.0, 21.0), (68.0, 12.0), (76.0, 0.0), (82.0, -10.0),
           (90.0, -9.0))
_SHORT = HairStyle(profile=((-40.0, 0.004), (-10.0, 0.007), (15.0, 0.012), (45.0, 0.019), (90.0, 0.022)))
_LONG = HairStyle(
    hairline=_F_LINE + ((96.0, -9.0), (110.0, -12.0), (118.0, -45.0), (130.0, -80.0), (180.0, -85.0)), hang=True,
    profile=((-75.0, 0.016), (-55.0, 0.024), (-25.0, 0.026), (0.0, 0.020), (30.0, 0.019), (90.0, 0.022)),
    azimuth_gain=((0.0, 0.75), (60.0, 1.0), (180.0, 1.0)), ramp_deg=10.0)
_BOB = HairStyle(
    hairline=_F_LINE + ((96.0, -9.0), (110.0, -12.0), (118.0, -42.0), (130.0, -55.0), (180.0, -58.0)), hang=True,
    profile=((-55.0, 0.036), (-35.0, 0.032), (-10.0, 0.024), (20.0, 0.020), (50.0, 0.022), (90.0, 0.024)),
    azimuth_gain=((0.0, 0.7), (50.0, 1.0), (180.0, 1.0)), ramp_deg=9.0)
_RECEDING = HairStyle(
    hairline=((0.0, 36.0), (15.0, 37.0), (30.0, 41.0), (45.0, 34.0), (58.0, 22.0), (68.0, 12.0), (76.0, -4.0),
              (80.0, -20.0), (86.0, -22.0), (90.0, -14.0), (112.0, -13.0), (122.0, -18.0), (135.0, -24.0),
              (155.0, -32.0), (180.0, -35.0)),
    profile=((-40.0, 0.003), (-10.0, 0.005), (15.0, 0.009), (45.0, 0.013), (90.0, 0.014)))
_SET = HairStyle(  # an older woman's short, full set: volume on top, close at the sides and nape
    hairline=_F_LINE + ((96.0, -9.0), (115.0, -18.0), (135.0, -30.0), (180.0, -40.0)),
    profile=((-40.0, 0.004), (-20.0, 0.009), (0.0, 0.015), (30.0, 0.023), (60.0, 0.029), (90.0, 0.030)),
    azimuth_gain=((0.0, 0.9), (90.0, 0.8), (180.0, 1.0)), ramp_deg=18.0)
_HORSESHOE = HairStyle(  # male-pattern baldness: a fringe of short hair round the sides and back
    hairline=HAIRLINE,
    top=((0.0, -90.0), (50.0, -90.0), (62.0, 2.0), (80.0, 14.0), (120.0, 20.0), (180.0, 24.0)),
    profile=((-40.0, 0.003), (-10.0, 0.004), (15.0, 0.005), (90.0, 0.005)), ramp_deg=8.0)

# ---------------------------------------------------------------------------------------- skin
#: base skin albedo by Fitzpatrick type (II = the default head's)
SKIN = {"I": (0.90, 0.72, 0.62), "II": (0.84, 0.63, 0.52), "III": (0.76, 0.55, 0.42), "IV": (0.62, 0.43, 0.30),
        "V": (0.44, 0.29, 0.20), "VI": (0.30, 0.19, 0.13)}

RECIPES: tuple[Recipe, ...] = (
    Recipe("amara", "female", 29, "VI", 3501, "young woman, deep brown skin, long black hair",
           _LONG, Look(skin=SKIN["VI"], redness=0.25, periorbital=1.4, beard=0.0, lip=(0.34, 0.19, 0.18),
                       hair=(0.05, 0.04, 0.034), brow=(0.03, 0.025, 0.022), iris=(0.16, 0.09, 0.05),
                       iris_outer=(0.10, 0.07, 0.05), brow_density=0.9, age=0.0,
                       sheen=0.35, strand_var=0.6, rim=0.12),  # black hair that reads on the panel's black
           sex_score=-2.2, age_score=-1.2, ipd_mm=61.5),
    Recipe("james", "male", 32, "II", 3502, "young man, fair skin, short brown hair",
           _SHORT, Look(skin=SKIN["II"], hair=(0.22, 0.15, 0.09), brow=(0.15, 0.10, 0.065),
                        iris=(0.30, 0.36, 0.40), iris_outer=(0.20, 0.24, 0.28), age=0.05),
           sex_score=2.0, age_score=-1.0, ipd_mm=64.0),
    Recipe("mei", "female", 50, "III", 3503, "middle-aged woman, light brown skin, black bob going grey",
           _BOB, Look(skin=SKIN["III"], redness=0.6, periorbital=1.2, beard=0.0, lip=(0.62, 0.35, 0.33),
                      hair=(0.045, 0.035, 0.03), brow=(0.05, 0.04, 0.035), grey=0.12, iris=(0.20, 0.12, 0.06),
                      iris_outer=(0.13, 0.09, 0.06), brow_density=0.75, age=0.45),
           sex_score=-2.0, age_score=0.4, ipd_mm=61.0),
    Recipe("rafael", "male", 48, "IV", 3504, "middle-aged man, olive-brown skin, receding black hair greying",
           _RECEDING, Look(skin=SKIN["IV"], redness=0.45, periorbital=1.3, beard=1.6, lip=(0.52, 0.29, 0.26),
                           hair=(0.05, 0.04, 0.035), brow=(0.05, 0.04, 0.035), grey=0.25, iris=(0.22, 0.13, 0.06),
                           iris_outer=(0.14, 0.10, 0.06), brow_density=1.1, age=0.5),
           sex_score=2.2, age_score=0.5, ipd_mm=64.5),
    Recipe("helen", "female", 71, "I", 3505, "older woman, very fair skin, short full grey hair",
           _SET, Look(skin=SKIN["I"], redness=1.3, periorbital=1.1, beard=0.0, lip=(0.70, 0.44, 0.44),
                      hair=(0.55, 0.53, 0.50), brow=(0.24, 0.19, 0.15), grey=0.75, brow_grey=0.35,
                      iris=(0.36, 0.48, 0.58), iris_outer=(0.22, 0.30, 0.38), brow_density=0.75, age=1.0,
                      hair_value=0.6),
           sex_score=-1.8, age_score=2.0, ipd_mm=61.0, pain_gains={"AU4": 1.247}),
    Recipe("kwame", "male", 68, "V", 3506, "older man, dark brown skin, bald crown, short grey hair",
           _HORSESHOE, Look(skin=SKIN["V"], redness=0.3, periorbital=1.4, beard=1.2, lip=(0.38, 0.22, 0.20),
                            hair=(0.10, 0.09, 0.085), brow=(0.12, 0.11, 0.10), grey=0.7, iris=(0.15, 0.09, 0.05),
                            iris_outer=(0.10, 0.07, 0.05), brow_density=0.8, age=1.0),
           sex_score=2.0, age_score=2.0, ipd_mm=64.0),
)


def recipe(name: str) -> Recipe:
    for r in RECIPES:
        if r.name == name:
            return r
    raise KeyError(f"no patient recipe {name!r}; expected one of {[r.name for r in RECIPES]}")
