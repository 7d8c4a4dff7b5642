"""The segmentation baseline: PCT trained on synthetic scans, evaluated on real ones.

The paper's Table 2 recipe (``config``: TOML -> dataclasses, Table 2 defaults) on the pieces:

- ``data``: scenes (bimscan datasets and clouds, foreign LAS/LAZ/PLY/text scans, S3DIS rooms),
  labels mapped onto the training classes (``mapping``, mapping files as data), training
  tiles kept in bounded memory.
- ``blocks``: vertical columns of N points, sampling/padding, normalisation, full-coverage passes.
- ``model``: PCT segmentation network (offset attention), padding masked everywhere.
- ``train``: Adam + OneCycleLR, accumulation, AMP/GradScaler, EMA, DDP, checkpoints, curves.
- ``metrics``: OA, mIoU, mAcc, FWIoU, kappa from one confusion matrix.
- ``infer``: every point of a scene labelled by voting overlapping blocks, in bounded memory.
- ``evaluate`` / ``predict``: per-scene tables (Table 3) and labelled clouds.

torch is imported by ``model``, ``train``, ``infer``, ``evaluate``, ``predict`` and
``checkpoint`` only; ``metrics``, ``blocks``, ``config``, ``mapping`` and ``data`` work without it.
"""
