"""Survey simulator: synthetic floors, magnetic fields, walkers, phones and radios.

Everything is computed from one integer seed; every component draws from its own child
generator (:func:`survey.sim.rng.child_rng`), so adding a walk or a component does not change the
numbers of the others. Modules, one job each:

- :mod:`~survey.sim.rng`, :mod:`~survey.sim.signals`, :mod:`~survey.sim.rotations`: seeding,
  smooth random processes, quaternion algebra;
- :mod:`~survey.sim.floorplan`: floor outline, shop blocks, corridors, walk lines;
- :mod:`~survey.sim.routes`: the waypoint graph on the walk lines and random survey routes;
- :mod:`~survey.sim.mapjson`: the floor's ``geojson_map.json``, ``floor_info.json`` and
  ``planned_routes.geojson`` as dictionaries;
- :mod:`~survey.sim.field`: the magnetic field (earth field + steel anomalies);
- :mod:`~survey.sim.walker`: true path, timeline, steps and waypoint clicks of one walk;
- :mod:`~survey.sim.imu`: attitude, accelerometer, gyroscope and rotation vector;
- :mod:`~survey.sim.devices`: phone models, soft/hard iron, calibration sessions, magnetometer;
- :mod:`~survey.sim.radio`: Wi-Fi access points and BLE beacons;
- :mod:`~survey.sim.assemble`: a walk's streams as a :class:`~survey.trace_format.Trace`;
- :mod:`~survey.sim.output`: deterministic JSON / Parquet bytes;
- :mod:`~survey.sim.site`: parameters, presets and :func:`simulate_site` (the only module that
  writes files);
- :mod:`~survey.sim.cli`: the ``indoormap simulate`` command.

Import the heavy parts by name, e.g. ``from survey.sim.site import SiteParams, simulate_site``.
"""
