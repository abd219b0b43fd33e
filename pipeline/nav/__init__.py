"""Own-ship integrated navigation (gyro/GNSS/log paper): modes, dead reckoning, outages."""
