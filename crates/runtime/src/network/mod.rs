//! Renderer networks.
