//! Serial DAQ backend (in progress).
