"""The P6 family: its model (model.py), cycle loop (core.py), instruction table (p6.toml),
machine table (p6_machine.toml) and view (view.py). Registered in sim/cpus/families.py."""
