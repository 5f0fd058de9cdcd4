"""Training code of the learned detector: the keypoint network and the patch refiner.

    python -m uav_struct_env.training.train_detector --data DIR --val DIR --out DIR
    python -m uav_struct_env.training.train_refiner --data DIR --val DIR --out DIR
    uav-struct adapt building.ifc     # both networks fine-tuned on renders of one building (.adapt)

Needs the ``train`` extra (torch). See localization/detect/models/MODEL_CARD.md. :mod:`.policy_files`
reads a trained viewpoint policy (``examples/train_viewpoint_ppo.py``) without unpickling.
"""
