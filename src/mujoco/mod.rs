//! The MuJoCo side: bindings, read-only views of the model and data, the scene of
//! indenters, the plugin callbacks behind the C shim, and the scene geoms its viewer
//! callback adds. The only module that touches
//! MuJoCo's C API.
pub mod draw;
pub mod gel_contacts;
mod mesh_cache;
pub mod plugin;
pub mod scene;
pub mod sys;
pub mod view;
