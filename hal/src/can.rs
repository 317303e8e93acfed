//! SocketCAN backend (in progress).
