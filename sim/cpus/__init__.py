"""CPU families: presets, instruction tables and timing models.

The package holds no code (its modules import one way): :mod:`sim.cpus.presets` (a preset file),
:mod:`sim.cpus.overrides` (a preset with overrides, each value checked), :mod:`sim.cpus.machine`
(machine labels and the resolved :class:`sim.cpus.machine.Machine`), :mod:`sim.cpus.build`
(a machine's timing model: ``make_model``), and the families' modules.
"""
