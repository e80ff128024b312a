"""The built-in generic two-spool high-bypass turbofan (C-MAPSS-like, 90,000 lbf class).

Layers, each a small module:

- ``xp``: the array namespaces the cycle is written against: ``NP`` (numpy, a
  batch of engines) and ``SCALAR`` (``math`` on Python floats, one engine).
- ``gas``: cp(T, far), enthalpy, entropy function, isentropic temperature.
- ``atmosphere``: ISA, inlet (T2, P2, theta, delta), unit constants.
- ``maps``: generic compressor maps with stall lines, turbine maps.
- ``components``: compression, expansion, burner, nozzles, bleed valve.
- ``design``: design point fitted to C-MAPSS FD001 and the sizing of maps and areas.
- ``health``: the 13 health / actuator-bias parameters, seed 002 fault library.
- ``actuators``: VSV / VBV schedules, power setting -> corrected fan speed.
- ``turbofan``: the cycle (gas path with five quasi-steady unknowns), spool and
  heat-soak dynamics, sensors and aux outputs:
  ``evaluate(x, u, env, health, guess)``, ``derivatives(...)``, ``outputs(...)``,
  and the lower level ``operating`` / ``gas_path`` / ``outputs_from_stations``.
- ``steady``: ``steady_state(env, power=... | wf=..., health)``.
- ``controller``: fan-speed governor with ratio-unit limits and VSV / VBV schedules.
- ``transient``: ``simulate(...)`` closed-loop flights of a batch of engines;
  ``transient_one``: the same for one engine on floats (chosen by ``simulate``).
- ``sensors``: names, units (C-MAPSS units) and noise of sensors and aux outputs.
- ``linearize``: ``linearize(alt, mach, power, dtamb, health, dt)`` -> LinearModel.
- ``schedule``: linear models and corrected trims on an operating-condition grid.

Shapes: x [4] or [B, 4] (Nf rpm, Nc rpm, TMHPC degR, TMHPT degR); u [3] or
[B, 3] (Wf pps, VSV % open, VBV % open); env [3] or [B, 3] (altitude ft, Mach,
dTamb K); health [13] or [B, 13] percent. Errors: ``errors.EnvelopeError``
(ValueError) outside the envelope, ``errors.EngineConvergenceError``
(RuntimeError) where a balance does not converge.
"""
