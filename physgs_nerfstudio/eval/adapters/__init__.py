"""Dataset layouts read by ``physgs eval``: ABO-500 (+ NeRF2Physics predictions), friction/hardness points,
terrain classes, plain tables, and our export's report.json."""
