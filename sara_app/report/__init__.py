"""The evidence report of a cell (``sara-app report``, the dashboard's report button): what an
auditor needs to judge the cell and to confirm that the running cell is the one judged.

- :mod:`.stopping`: the robot's stopping times and distances at its limits beside the ISO 13855
  separation distance for the same stop;
- :mod:`.evidence`: gathers every section (configuration and checksum, containment on
  recordings, thresholds, audit log, stops, closed-loop and adversarial runs per mode);
- :mod:`.html`: renders it as one self-contained HTML page (plots embedded as PNG);
- :mod:`.pdf`: prints that page to PDF with Debian's chromium, where installed.
"""
