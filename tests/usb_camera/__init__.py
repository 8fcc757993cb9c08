"""Tests of the HID USB relay and gphoto2 camera drivers, their simulators, and discovery."""
