"""Data shipped with pmht-opt: the example missions (``pmht_opt.io.example_mission``)."""
