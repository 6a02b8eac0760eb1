//! The MuJoCo side: bindings, read-only views of the model and data, the scene of
//! indenters, and the plugin callbacks behind the C shim. The only module that touches
//! MuJoCo's C API.
mod mesh_cache;
pub mod plugin;
pub mod scene;
pub mod sys;
pub mod view;
