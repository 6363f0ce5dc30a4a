"""The homing loop and its controllers: measurements in, velocity commands out."""
