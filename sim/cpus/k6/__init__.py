"""The K6 family: its model (model.py), cycle loop (core.py), instruction table (k6.toml),
machine table (k6_machine.toml) and view (view.py). Registered in sim/cpus/families.py."""
