"""Face editing (Sec. 5.2, 5.3): manifold traversal, relighting and lighting transfer, measured.

* :mod:`disent.edit.traversal`  Deep Manifold Traversal and barycenter traversal on chosen codes;
* :mod:`disent.edit.relight`    relight by ``Z_L``, transfer with detailed albedo, the ratio baseline;
* :mod:`disent.edit.classifier` the measuring net (attributes, light, pose, identity) trained on truth;
* :mod:`disent.edit.measure`    success / leakage and relighting-accuracy tables on SynthFaces;
* ``python -m disent.edit``     the commands (see :mod:`disent.edit.__main__`).
"""

from disent.edit.relight import (
    directional_light,
    named_light,
    ratio_relight,
    relight,
    transfer_lighting,
    with_light,
)
from disent.edit.traversal import (
    ATTRIBUTES,
    DEFAULT_MANIFOLDS,
    AttributePool,
    barycenter,
    choose_bandwidth,
    dmt,
    encode_pool,
    traverse,
    witness,
)

__all__ = [
    "ATTRIBUTES",
    "DEFAULT_MANIFOLDS",
    "AttributePool",
    "barycenter",
    "choose_bandwidth",
    "dmt",
    "encode_pool",
    "traverse",
    "witness",
    "directional_light",
    "named_light",
    "ratio_relight",
    "relight",
    "transfer_lighting",
    "with_light",
]
