"""The python-gphoto2 constants the rig uses, with the values of the real module (2.6.4).

``tests/usb_camera/test_fake_gphoto2.py`` checks every value here against the real module.
"""

from __future__ import annotations

GP_OK = 0
GP_ERROR = -1
GP_ERROR_BAD_PARAMETERS = -2
GP_ERROR_NO_MEMORY = -3
GP_ERROR_LIBRARY = -4
GP_ERROR_UNKNOWN_PORT = -5
GP_ERROR_NOT_SUPPORTED = -6
GP_ERROR_IO = -7
GP_ERROR_FIXED_LIMIT_EXCEEDED = -8
GP_ERROR_TIMEOUT = -10
GP_ERROR_IO_SUPPORTED_SERIAL = -20
GP_ERROR_IO_SUPPORTED_USB = -21
GP_ERROR_IO_INIT = -31
GP_ERROR_IO_READ = -34
GP_ERROR_IO_WRITE = -35
GP_ERROR_IO_UPDATE = -37
GP_ERROR_IO_SERIAL_SPEED = -41
GP_ERROR_IO_USB_CLEAR_HALT = -51
GP_ERROR_IO_USB_FIND = -52
GP_ERROR_IO_USB_CLAIM = -53
GP_ERROR_IO_LOCK = -60
GP_ERROR_HAL = -70
GP_ERROR_CORRUPTED_DATA = -102
GP_ERROR_FILE_EXISTS = -103
GP_ERROR_MODEL_NOT_FOUND = -105
GP_ERROR_DIRECTORY_NOT_FOUND = -107
GP_ERROR_FILE_NOT_FOUND = -108
GP_ERROR_DIRECTORY_EXISTS = -109
GP_ERROR_CAMERA_BUSY = -110
GP_ERROR_PATH_NOT_ABSOLUTE = -111
GP_ERROR_CANCEL = -112
GP_ERROR_CAMERA_ERROR = -113
GP_ERROR_OS_FAILURE = -114
GP_ERROR_NO_SPACE = -115

#: ``gp_result_as_string`` texts of libgphoto2 2.5.34.
ERROR_STRINGS: dict[int, str] = {
    GP_OK: "No error",
    GP_ERROR: "Unspecified error",
    GP_ERROR_BAD_PARAMETERS: "Bad parameters",
    GP_ERROR_NO_MEMORY: "Out of memory",
    GP_ERROR_LIBRARY: "Error loading a library",
    GP_ERROR_UNKNOWN_PORT: "Unknown port",
    GP_ERROR_NOT_SUPPORTED: "Unsupported operation",
    GP_ERROR_IO: "I/O problem",
    GP_ERROR_FIXED_LIMIT_EXCEEDED: "Fixed limit exceeded",
    GP_ERROR_TIMEOUT: "Timeout reading from or writing to the port",
    GP_ERROR_IO_SUPPORTED_SERIAL: "Serial port not supported",
    GP_ERROR_IO_SUPPORTED_USB: "USB port not supported",
    GP_ERROR_IO_INIT: "Error initializing the port",
    GP_ERROR_IO_READ: "Error reading from the port",
    GP_ERROR_IO_WRITE: "Error writing to the port",
    GP_ERROR_IO_UPDATE: "Error updating the port settings",
    GP_ERROR_IO_SERIAL_SPEED: "Error setting the serial port speed",
    GP_ERROR_IO_USB_CLEAR_HALT: "Error clearing a halt condition on the USB port",
    GP_ERROR_IO_USB_FIND: "Could not find the requested device on the USB port",
    GP_ERROR_IO_USB_CLAIM: "Could not claim the USB device",
    GP_ERROR_IO_LOCK: "Could not lock the device",
    GP_ERROR_HAL: "libhal error",
    GP_ERROR_CORRUPTED_DATA: "Corrupted data",
    GP_ERROR_FILE_EXISTS: "File exists",
    GP_ERROR_MODEL_NOT_FOUND: "Unknown model",
    GP_ERROR_DIRECTORY_NOT_FOUND: "Directory not found",
    GP_ERROR_FILE_NOT_FOUND: "File not found",
    GP_ERROR_DIRECTORY_EXISTS: "Directory exists",
    GP_ERROR_CAMERA_BUSY: "I/O in progress",
    GP_ERROR_PATH_NOT_ABSOLUTE: "Path not absolute",
    GP_ERROR_CANCEL: "Operation cancelled",
    GP_ERROR_CAMERA_ERROR: "Camera could not complete operation",
    GP_ERROR_OS_FAILURE: "OS error in camera communication",
    GP_ERROR_NO_SPACE: "Not enough free space",
}

GP_WIDGET_WINDOW = 0
GP_WIDGET_SECTION = 1
GP_WIDGET_TEXT = 2
GP_WIDGET_RANGE = 3
GP_WIDGET_TOGGLE = 4
GP_WIDGET_RADIO = 5
GP_WIDGET_MENU = 6
GP_WIDGET_BUTTON = 7
GP_WIDGET_DATE = 8

GP_CAPTURE_IMAGE = 0
GP_CAPTURE_MOVIE = 1
GP_CAPTURE_SOUND = 2

GP_FILE_TYPE_PREVIEW = 0
GP_FILE_TYPE_NORMAL = 1
GP_FILE_TYPE_RAW = 2

GP_EVENT_UNKNOWN = 0
GP_EVENT_TIMEOUT = 1
GP_EVENT_FILE_ADDED = 2
GP_EVENT_FOLDER_ADDED = 3
GP_EVENT_CAPTURE_COMPLETE = 4
GP_EVENT_FILE_CHANGED = 5

GP_VERSION_SHORT = 0
GP_VERSION_VERBOSE = 1

LIBRARY_VERSION = ("2.5.34", "fake camlibs", "no ltdl")
"""What :func:`gp_library_version` reports (the first field matches the real wheel's library)."""
