"""The benchmark's object sets by name, with the hand each is benchmarked with.

- "scaled": the held-out random_urdfs 900-999, scaled so each fits the hand (the benchmarks' objects so far),
  with graspd's default hand;
- "scaled-training": the training random_urdfs 000-899 (but the broken one), scaled and handled alike: the set
  to look at what the scaled benchmarks fail on without looking at their held-out objects;
- "household": the held-out household models (graspd_lab.world.household.HELD_OUT) at their true size, with a
  Panda-like hand (7.5 cm opening; the simulated fingers press with ExecutionParams.finger_force, 40 N), as the
  outside clutter benchmarks use;
- "household-training": the other household models, the ones training draws from, with the same hand: the set
  to tune selection and execution on, so that the held-out set stays unseen until a result is reported;
- "household-training-heavy": household.heavy_training_names, those of them of household.HEAVY_MASS or more
  (their URDF's mass), the same hand: the objects that slip out of 40 N fingers when grasped off their centre of
  mass, to tune against that failure;
- "household-training-flat": household.flat_training_names, those of them under household.FLAT_THICKNESS thick
  (packets, a phone, tape), the same hand: the objects held only by their edges above the table.
The benchmark's reported figures come from the held-out sets only.  Each set has its stop rule
(graspd_lab.sim.protocol.STOP_RULES): the household sets the standard clutter-removal benchmark's (a round ends
after two failures in a row, or when no grasp is found), the scaled set the IJRR paper's that its figures were
always measured with.
"""

from __future__ import annotations

from graspd.core.hand import HandGeometry, hand_preset
from graspd_lab.sim.objects import TEST_OBJECT_IDS
from graspd_lab.world import household
from graspd_lab.world.objects import USABLE_TRAINING_URDFS

OBJECT_SETS = ("scaled", "scaled-training", "household", "household-training", "household-training-heavy",
               "household-training-flat")

#: A Panda-like hand: the panda preset's fingers (45 mm reach, 10 mm thick) and 60 mm body behind the finger
#: roots, opening 75 mm (outer faces 95 mm apart).
PANDA_LIKE = hand_preset("panda").with_opening(0.075)


def object_set_ids(name: str) -> tuple[int, ...]:
    """The simulator object ids of a set (ValueError for an unknown name)."""
    if name == "scaled":
        return TEST_OBJECT_IDS
    if name == "scaled-training":
        return USABLE_TRAINING_URDFS
    if name == "household":
        return tuple(household.household_id(n) for n in household.HELD_OUT)
    if name == "household-training":
        return tuple(household.household_id(n) for n in household.training_names())
    if name == "household-training-heavy":
        return tuple(household.household_id(n) for n in household.heavy_training_names())
    if name == "household-training-flat":
        return tuple(household.household_id(n) for n in household.flat_training_names())
    raise ValueError(f"object set must be one of {OBJECT_SETS}, got {name!r}")


def object_set_hand(name: str) -> HandGeometry:
    """The hand a set is benchmarked with (ValueError for an unknown name)."""
    object_set_ids(name)
    return PANDA_LIKE if name.startswith("household") else HandGeometry()


def object_set_stop(name: str) -> str:
    """The stop rule a set is benchmarked with (ValueError for an unknown name)."""
    object_set_ids(name)
    return "standard" if name.startswith("household") else "ijrr"


def object_label(object_id: int) -> str:
    """How results files name a simulator object: a household model's name, else its id."""
    return household.household_name(object_id) if household.is_household_id(object_id) else str(object_id)


def describe(name: str) -> str:
    """One line for a results file: what the set's objects are."""
    if name == "household":
        return (f"the {len(household.HELD_OUT)} held-out household models (graspd_lab.world.household.HELD_OUT) "
                "at their true size, with a Panda-like hand (7.5 cm opening, 40 N per finger)")
    if name == "household-training":
        return (f"the {len(household.training_names())} household training models (not the held-out ones; for "
                "tuning) at their true size, with a Panda-like hand (7.5 cm opening, 40 N per finger)")
    if name == "household-training-heavy":
        return (f"the {len(object_set_ids(name))} household training models of {household.HEAVY_MASS} kg or more "
                "(not the held-out ones; for tuning) at their true size, with a Panda-like hand (7.5 cm opening, 40 N "
                "per finger)")
    if name == "household-training-flat":
        return (f"the {len(object_set_ids(name))} household training models under "
                f"{household.FLAT_THICKNESS * 100:.0f} cm thick (not the held-out ones; for tuning) at their true "
                "size, with a Panda-like hand (7.5 cm opening, 40 N per finger)")
    if name == "scaled-training":
        return ("pybullet_data random_urdfs 000-899 (the training objects; for tuning), scaled to the hand")
    return "pybullet_data random_urdfs 900-999 (held out from training), scaled to the hand"
