//! Serial DAQ wire protocol (in progress).
