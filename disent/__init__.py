"""disent: intrinsic face disentangling (Shu et al., CVPR 2017), re-implemented and measured."""

__version__ = "0.1.0"
