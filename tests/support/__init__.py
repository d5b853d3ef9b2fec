"""What the tests share: the live server and its line client, the long-suite marks, simulated
time for the monitors, the navigation tests' ground truth, simulated ToF frames for the bounds map,
recordings read back, and the reliability suites' wire fuzzing, /proc probes and figures. Tests
import these modules; the fixtures in ``tests/conftest.py`` are built on them, and no test imports
another test."""
