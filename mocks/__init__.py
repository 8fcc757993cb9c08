"""Stand-ins for hardware: byte-level emulators, a fake USB backend, a fake gphoto2, the digital twin."""
