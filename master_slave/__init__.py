"""Master and slave Omni processes of the teleoperation demo (``python -m master_slave.*``)."""
