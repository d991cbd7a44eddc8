"""The PySide6 desktop studio: main window, panels, controllers."""
