"""The web viewer (``/viewer``): its static page, and the takes and rig description its helper routes serve."""
