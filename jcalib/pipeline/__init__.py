"""Images and capture sessions to observations; triangulated points and work-object frames from files."""
