"""Real photos: a folder loader (:mod:`~disent.data.photos.folder`) whose items carry the paper's pseudo ground
truth, made from 68 landmarks and the project's face model (:mod:`~disent.data.photos.pseudo_gt`), and the
study of the bundled photos (:mod:`~disent.data.photos.study`, ``python -m disent.data.photos``).  Running
trained models on photos is evaluation: :mod:`disent.eval.photos` and ``python -m disent.photos``."""
