"""Tests of the device drivers, their emulators and the transport under them."""
