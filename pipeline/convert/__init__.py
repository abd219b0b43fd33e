"""Legacy captures (NMEA text, AIS CSV, ASTERIX framings, pcap) converted to MCAP."""
