"""``python -m uav_struct_env.study``: the paper's study (see ``--help``)."""

from uav_struct_env.study.study import main

if __name__ == "__main__":
    raise SystemExit(main())
