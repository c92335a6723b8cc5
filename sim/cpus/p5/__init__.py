"""The P5 family: its model (model.py), cycle loop (core.py), instruction table (p5.toml),
machine table (p5_machine.toml) and view (view.py). Registered in sim/cpus/families.py."""
