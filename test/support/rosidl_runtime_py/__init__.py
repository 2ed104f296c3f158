"""Stand-in for rosidl_runtime_py (only ``utilities.get_message`` / ``get_service``)."""
