//! GNSS: NMEA 0183 parsing and the position prior. Pure; the serial reader lives in the shell.
