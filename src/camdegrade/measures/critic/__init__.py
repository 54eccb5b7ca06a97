"""The learned critic: can a small CNN tell real captures from simulated ones? Its inputs (:mod:`.patches`), the
test on calibration and held-out pairs (:mod:`.core`), the test on one set split by scene and repeated over seeds
(:mod:`.repeated`), and why it decides as it does (:mod:`.explain`, imported on its own)."""

from camdegrade.measures.critic.core import (
    BATCH,
    BOOTSTRAP_ROUNDS,
    INTENSITY_EDGES,
    LEARNING_RATE,
    RADIUS_EDGES,
    STEPS,
    CriticNet,
    CriticResult,
    bootstrap_interval,
    critic_test,
    logits,
    score,
    score_logits,
    train_critic,
)
from camdegrade.measures.critic.patches import (
    FLAT_SHARE,
    GRID,
    IMAGE_ONLY_PLANES,
    PATCH,
    PATCHES_PER_PAIR,
    PLANES,
    PairFeatures,
    Patches,
    pair_features,
)
from camdegrade.measures.critic.repeated import (
    SPLIT_PASSES,
    CriticSpread,
    alternate_scenes,
    repeated_critic_test,
    split_critic_test,
)

__all__ = [
    "BATCH",
    "BOOTSTRAP_ROUNDS",
    "FLAT_SHARE",
    "GRID",
    "IMAGE_ONLY_PLANES",
    "INTENSITY_EDGES",
    "LEARNING_RATE",
    "PATCH",
    "PATCHES_PER_PAIR",
    "PLANES",
    "RADIUS_EDGES",
    "SPLIT_PASSES",
    "STEPS",
    "CriticNet",
    "CriticResult",
    "CriticSpread",
    "PairFeatures",
    "Patches",
    "alternate_scenes",
    "bootstrap_interval",
    "critic_test",
    "logits",
    "pair_features",
    "repeated_critic_test",
    "score",
    "score_logits",
    "split_critic_test",
    "train_critic",
]
