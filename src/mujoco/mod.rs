//! MuJoCo 2.2.2: generated FFI (`ffi`) and the safe wrapper the rest of mjsafe uses.
//!
//! This module is the only place with `unsafe`. It owns `mjModel`/`mjData` (freed on drop),
//! exposes their arrays as slices, and routes MuJoCo's process-global `mjcb_control` to the
//! [`ControlHook`] of the episode stepping on the *current thread* (see [`Simulation::step`]).

#[allow(unsafe_op_in_unsafe_fn)]
#[cfg(test)]
pub(crate) mod counting_alloc;
mod ffi;
mod sizes;
pub use sizes::{last_attribute_and_count, MAX_NSTACK};

use std::cell::RefCell;
use std::ffi::{CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::ptr::NonNull;
use std::sync::Once;

/// The MuJoCo version mjsafe is written and tested against (`mj_version()` value).
pub const REQUIRED_VERSION: i32 = 222;

#[derive(Debug, thiserror::Error)]
pub enum MjError {
    #[error("MuJoCo library version {found} is loaded, but mjsafe needs {REQUIRED_VERSION} (2.2.2, Debian package libmujoco-dev)")]
    WrongVersion { found: i32 },
    #[error("cannot read MJCF file {path}: {reason}")]
    Io { path: String, reason: std::io::Error },
    #[error("MuJoCo rejected the MJCF model {origin}: {message}")]
    Load { origin: String, message: String },
    #[error("the MJCF model {origin} is refused before MuJoCo compiles it: {message}")]
    Sizes { origin: String, message: String },
    #[error("MJCF text for {origin} contains a NUL byte")]
    NulInXml { origin: String },
    #[error("the model has no {kind} named `{name}`")]
    MissingName { kind: &'static str, name: String },
    #[error("the model's {name} is {value}: expected {expected}")]
    InvalidValue {
        name: &'static str,
        value: f64,
        expected: &'static str,
    },
    #[error("MuJoCo could not allocate mjData for the model")]
    DataAllocation,
    #[error("MuJoCo could not allocate a copy of the model")]
    ModelCopy,
    #[error("the control callback panicked at t = {time}: {message}")]
    CallbackPanicked { time: f64, message: String },
    #[error("MuJoCo warning during the step at t = {time}: {message}")]
    Unstable { time: f64, message: String },
    /// `mju_error` during a step or a forward pass: the run's `mjData` is discarded.
    #[error("MuJoCo stopped the step at t = {time:.3} s with an error: {message}")]
    Runtime { time: f64, message: String },
}

/// Checks that the linked library is MuJoCo 2.2.2.
pub fn check_version() -> Result<(), MjError> {
    let found = version();
    if found == REQUIRED_VERSION {
        Ok(())
    } else {
        Err(MjError::WrongVersion { found })
    }
}

/// `mj_version()`: 222 for MuJoCo 2.2.2.
pub fn version() -> i32 {
    // SAFETY: no arguments, no state.
    unsafe { ffi::mj_version() }
}

/// `mj_versionString()`, e.g. "2.2.2".
pub fn version_string() -> String {
    // SAFETY: returns a pointer to a static NUL-terminated string.
    unsafe { CStr::from_ptr(ffi::mj_versionString()) }
        .to_string_lossy()
        .into_owned()
}

/// Object kinds for name lookups.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjKind {
    Body,
    Joint,
    Geom,
    Site,
    Actuator,
    Numeric,
}

impl ObjKind {
    fn raw(self) -> ffi::mjtObj {
        match self {
            ObjKind::Body => ffi::mjtObj::mjOBJ_BODY,
            ObjKind::Joint => ffi::mjtObj::mjOBJ_JOINT,
            ObjKind::Geom => ffi::mjtObj::mjOBJ_GEOM,
            ObjKind::Site => ffi::mjtObj::mjOBJ_SITE,
            ObjKind::Actuator => ffi::mjtObj::mjOBJ_ACTUATOR,
            ObjKind::Numeric => ffi::mjtObj::mjOBJ_NUMERIC,
        }
    }
    fn label(self) -> &'static str {
        match self {
            ObjKind::Body => "body",
            ObjKind::Joint => "joint",
            ObjKind::Geom => "geom",
            ObjKind::Site => "site",
            ObjKind::Actuator => "actuator",
            ObjKind::Numeric => "custom numeric",
        }
    }
}

/// Numerical integrator selected in the model (`<option integrator=…>`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    Euler,
    Rk4,
    Implicit,
}

impl Integrator {
    /// Calls of `mjcb_control` per `mj_step` in 2.2.2.
    pub fn callbacks_per_step(self) -> u32 {
        match self {
            Integrator::Rk4 => 4,
            Integrator::Euler | Integrator::Implicit => 1,
        }
    }
}

/// A compiled MuJoCo model (`mjModel`), freed on drop.
pub struct Model {
    ptr: NonNull<ffi::mjModel>,
}

// SAFETY: an mjModel is plain heap data; mjsafe never shares one mutably across threads.
unsafe impl Send for Model {}

unsafe extern "C" {
    /// `mj_loadXML` inside a C++ `try`/`catch` (src/mujoco/load_xml.cpp): an exception of
    /// MuJoCo's compiler becomes a null model with its message in `error`.
    fn mjsafe_load_xml(
        filename: *const std::os::raw::c_char,
        vfs: *const ffi::mjVFS,
        error: *mut std::os::raw::c_char,
        error_sz: std::os::raw::c_int,
    ) -> *mut ffi::mjModel;
    /// `mj_step` (`forward` 0) or `mj_forward` (1) behind `setjmp` (src/mujoco/guard.c): 1
    /// when MuJoCo raised an error ([`mjsafe_error_message`]); the data is then unusable.
    fn mjsafe_guarded(m: *const ffi::mjModel, d: *mut ffi::mjData, forward: std::os::raw::c_int)
        -> std::os::raw::c_int;
    /// The message of this thread's last error caught by [`mjsafe_guarded`].
    fn mjsafe_error_message() -> *const std::os::raw::c_char;
    /// The `mju_user_error` handler: jumps back to [`mjsafe_guarded`] (or, outside it or with
    /// a Rust frame in between, calls [`mjsafe_fatal_error`]).
    fn mjsafe_error_handler(message: *const std::os::raw::c_char);
    /// Around the control callback: no jump skips its Rust frames.
    fn mjsafe_enter_rust();
    fn mjsafe_leave_rust();
}

/// How many compiled models a thread keeps for texts compiled again ([`COMPILED`]).
const CACHED_MODELS: usize = 2;

/// Size of MuJoCo's error buffer for `mj_loadXML`.
const ERROR_BUFFER: usize = 1000;

thread_local! {
    /// One MuJoCo virtual file system per thread, initialised once (mj_defaultVFS zeroes its
    /// ~2 MB, which cost every episode's start-up): each load adds the model text as a file
    /// and deletes it again.
    static MODEL_VFS: std::cell::RefCell<Option<Box<ffi::mjVFS>>> = const { std::cell::RefCell::new(None) };
    /// The last [`CACHED_MODELS`] models compiled on this thread from text that names no other
    /// file, with that text, the most recently used last. A sweep or a search compiles one
    /// model text for every run (two with a footprint or a lead on MuJoCo: the bare model,
    /// whose hull places the added geoms, then the model with them); a copy of the compiled
    /// model (`mj_copyModel`) is that model without the parse and the compile, whose temporary
    /// `mjData` zeroed MuJoCo's stack several times per load.
    static COMPILED: std::cell::RefCell<Vec<(String, Model)>> = const { std::cell::RefCell::new(Vec::new()) };
    /// The `mjData` of the last simulation dropped on this thread: the next one of a model
    /// with the same sizes resets it (`mj_resetData`, what `mj_makeData` does after
    /// allocating) instead of allocating 4 MB that the allocator may have handed back to the
    /// system (the faults cost up to 2 ms of start-up).
    static SPARE_DATA: std::cell::RefCell<Option<SpareData>> = const { std::cell::RefCell::new(None) };
}

/// The `int` sizes that open `mjModel` (nq … nbuffer, before `opt`): `mj_makeData` lays out
/// `mjData` from them alone, so models with equal sizes can share one.
const SIZE_FIELDS: usize = std::mem::offset_of!(ffi::mjModel, opt) / std::mem::size_of::<std::os::raw::c_int>();
type Sizes = [std::os::raw::c_int; SIZE_FIELDS];

/// An `mjData` kept for reuse, with the model sizes it was made for; deleted when replaced.
struct SpareData {
    sizes: Sizes,
    ptr: NonNull<ffi::mjData>,
}

impl SpareData {
    /// The pointer, now owned by the caller.
    fn into_ptr(self) -> NonNull<ffi::mjData> {
        std::mem::ManuallyDrop::new(self).ptr
    }
}

impl Drop for SpareData {
    fn drop(&mut self) {
        // SAFETY: the spare owns its data.
        unsafe { ffi::mj_deleteData(self.ptr.as_ptr()) }
    }
}

/// Whether MJCF text can name another file (an `<include>`, a mesh, texture, height field or
/// skin): an attribute whose name starts with `file` (`file=`, `fileright=`, …). Such a model
/// also depends on those files, so it is never served from [`COMPILED`]. Conservative: the
/// word in a comment followed by `=` counts too.
fn names_other_files(xml: &str) -> bool {
    xml.match_indices("file").any(|(at, _)| {
        let rest = xml[at + 4..].trim_start_matches(|c: char| c.is_ascii_alphabetic());
        rest.trim_start().starts_with('=')
    })
}

impl Model {
    /// Loads and compiles an MJCF file.
    pub fn from_xml_file(path: &Path) -> Result<Model, MjError> {
        let xml = std::fs::read_to_string(path).map_err(|source| MjError::Io {
            path: path.display().to_string(),
            reason: source,
        })?;
        Self::from_xml_string(&xml, &path.display().to_string())
    }

    /// Compiles MJCF text held in memory (through MuJoCo's virtual file system).
    /// `origin` names the text in error messages (e.g. the file it came from); the files the
    /// text names are found from `origin`'s folder (the working directory if it has none).
    /// Text that names no other file and equals the last text compiled on this thread gets a
    /// copy of that model instead of a second compile.
    pub fn from_xml_string(xml: &str, origin: &str) -> Result<Model, MjError> {
        check_version()?;
        install_callback();
        let bytes = xml.as_bytes();
        if bytes.contains(&0) {
            return Err(MjError::NulInXml {
                origin: origin.to_string(),
            });
        }
        sizes::check_model_sizes(xml, origin).map_err(|message| MjError::Sizes {
            origin: origin.to_string(),
            message,
        })?;
        let cacheable = !names_other_files(xml);
        if cacheable {
            let cached = COMPILED.with(|cell| {
                let mut cache = cell.borrow_mut();
                let at = cache.iter().position(|(text, _)| text == xml)?;
                let entry = cache.remove(at);
                let copy = entry.1.try_clone();
                cache.push(entry);
                Some(copy)
            });
            if let Some(model) = cached {
                return model;
            }
        }
        let model = Self::compile(xml, origin)?;
        if cacheable {
            let copy = model.try_clone()?;
            COMPILED.with(|cell| {
                let mut cache = cell.borrow_mut();
                if cache.len() >= CACHED_MODELS {
                    cache.remove(0);
                }
                cache.push((xml.to_string(), copy));
            });
        }
        Ok(model)
    }

    /// A copy of the model (`mj_copyModel`): the same sizes, options and values.
    pub fn try_clone(&self) -> Result<Model, MjError> {
        // SAFETY: a live source model; a null destination makes MuJoCo allocate the copy.
        let raw = unsafe { ffi::mj_copyModel(std::ptr::null_mut(), self.ptr.as_ptr()) };
        NonNull::new(raw).map(|ptr| Model { ptr }).ok_or(MjError::ModelCopy)
    }

    /// `mj_loadXML` of the text through this thread's virtual file system.
    fn compile(xml: &str, origin: &str) -> Result<Model, MjError> {
        #[cfg(test)]
        tests::COMPILES.with(|n| n.set(n.get() + 1));
        let bytes = xml.as_bytes();
        // MuJoCo resolves `<include>`, mesh and texture paths from the directory of this name
        // (its VFS keeps only the file part), so it carries the model file's directory: the
        // resolved one, or as given if that is too long for MuJoCo's names.
        const NAME: &str = "mjsafe_model.xml";
        let fits = |dir: &Path| {
            CString::new(dir.join(NAME).into_os_string().into_encoded_bytes())
                .ok()
                .filter(|n| n.as_bytes().len() < ffi::mjMAXVFSNAME as usize)
        };
        let vfs_name = match Path::new(origin).parent().filter(|d| !d.as_os_str().is_empty()) {
            None => CString::new(NAME).expect("static name"),
            Some(dir) => match std::fs::canonicalize(dir)
                .ok()
                .and_then(|d| fits(&d))
                .or_else(|| fits(dir))
            {
                Some(name) => name,
                None if names_other_files(xml) => {
                    return Err(MjError::Load {
                        origin: origin.to_string(),
                        message: format!(
                            "its folder's path is too long for MuJoCo to find the files it names \
                             (at most {} bytes); move it or run from a folder nearer to it",
                            ffi::mjMAXVFSNAME as usize - NAME.len() - 2
                        ),
                    })
                }
                None => CString::new(NAME).expect("static name"),
            },
        };
        let mut error = vec![0 as std::os::raw::c_char; ERROR_BUFFER];
        let refused = || MjError::Load {
            origin: origin.to_string(),
            message: "MuJoCo's virtual file system refused the model text".into(),
        };
        let raw = MODEL_VFS.with(|cell| {
            let mut cell = cell.borrow_mut();
            let vfs = cell.get_or_insert_with(|| {
                // SAFETY: mj_defaultVFS initialises the whole (heap-allocated, ~2 MB) struct.
                unsafe {
                    let mut vfs: Box<std::mem::MaybeUninit<ffi::mjVFS>> = Box::new_uninit();
                    ffi::mj_defaultVFS(vfs.as_mut_ptr());
                    vfs.assume_init()
                }
            });
            // SAFETY: the VFS is initialised; the file buffer is sized by MuJoCo before we copy
            // into it, and the file is deleted (its buffer freed) before the VFS is used again.
            unsafe {
                ffi::mj_deleteFileVFS(&mut **vfs, vfs_name.as_ptr());
                if ffi::mj_makeEmptyFileVFS(&mut **vfs, vfs_name.as_ptr(), bytes.len() as i32) != 0 {
                    return Err(refused());
                }
                let slot = ffi::mj_findFileVFS(&**vfs, vfs_name.as_ptr());
                let dest = vfs.filedata[slot as usize] as *mut u8;
                std::ptr::copy_nonoverlapping(bytes.as_ptr(), dest, bytes.len());
                let model = mjsafe_load_xml(vfs_name.as_ptr(), &**vfs, error.as_mut_ptr(), ERROR_BUFFER as i32);
                ffi::mj_deleteFileVFS(&mut **vfs, vfs_name.as_ptr());
                Ok(model)
            }
        })?;
        match NonNull::new(raw) {
            Some(ptr) => Ok(Model { ptr }),
            None => {
                // SAFETY: MuJoCo NUL-terminates the error buffer.
                let text = unsafe { CStr::from_ptr(error.as_ptr()) }.to_string_lossy();
                // One line: MuJoCo puts the element's name and position on a second one.
                let message = text
                    .lines()
                    .map(str::trim)
                    .filter(|l| !l.is_empty())
                    .collect::<Vec<_>>()
                    .join("; ");
                Err(MjError::Load {
                    origin: origin.to_string(),
                    message,
                })
            }
        }
    }

    fn raw(&self) -> &ffi::mjModel {
        // SAFETY: ptr is a live mjModel owned by self.
        unsafe { self.ptr.as_ref() }
    }

    /// The sizes `mjData` is laid out from.
    fn sizes(&self) -> Sizes {
        // SAFETY: a live mjModel opens with SIZE_FIELDS ints (bindgen's layout of 2.2.2's
        // struct: no padding before `opt`), all set by the compiler or mj_copyModel.
        let ints = unsafe { std::slice::from_raw_parts(self.ptr.as_ptr() as *const std::os::raw::c_int, SIZE_FIELDS) };
        ints.try_into().expect("SIZE_FIELDS ints")
    }

    pub fn nq(&self) -> usize {
        self.raw().nq as usize
    }
    pub fn nv(&self) -> usize {
        self.raw().nv as usize
    }
    pub fn nu(&self) -> usize {
        self.raw().nu as usize
    }
    pub fn na(&self) -> usize {
        self.raw().na as usize
    }
    pub fn ngeom(&self) -> usize {
        self.raw().ngeom as usize
    }

    pub fn timestep(&self) -> f64 {
        self.raw().opt.timestep
    }

    pub fn set_timestep(&mut self, timestep: f64) {
        // SAFETY: ptr is live and uniquely borrowed.
        unsafe { self.ptr.as_mut() }.opt.timestep = timestep;
    }

    pub fn integrator(&self) -> Integrator {
        match self.raw().opt.integrator {
            x if x == ffi::mjtIntegrator::mjINT_RK4 as i32 => Integrator::Rk4,
            x if x == ffi::mjtIntegrator::mjINT_IMPLICIT as i32 => Integrator::Implicit,
            _ => Integrator::Euler,
        }
    }

    pub fn set_integrator(&mut self, integrator: Integrator) {
        let raw = match integrator {
            Integrator::Euler => ffi::mjtIntegrator::mjINT_EULER,
            Integrator::Rk4 => ffi::mjtIntegrator::mjINT_RK4,
            Integrator::Implicit => ffi::mjtIntegrator::mjINT_IMPLICIT,
        };
        // SAFETY: ptr is live and uniquely borrowed.
        unsafe { self.ptr.as_mut() }.opt.integrator = raw as i32;
    }

    /// Id of a named object, if it exists.
    pub fn id(&self, kind: ObjKind, name: &str) -> Option<usize> {
        let cname = CString::new(name).ok()?;
        // SAFETY: live model, NUL-terminated name.
        let id = unsafe { ffi::mj_name2id(self.ptr.as_ptr(), kind.raw() as i32, cname.as_ptr()) };
        (id >= 0).then_some(id as usize)
    }

    /// Id of a named object, or an error naming what is missing.
    pub fn require(&self, kind: ObjKind, name: &str) -> Result<usize, MjError> {
        self.id(kind, name).ok_or_else(|| MjError::MissingName {
            kind: kind.label(),
            name: name.to_string(),
        })
    }

    /// Name of an object by id.
    pub fn name(&self, kind: ObjKind, id: usize) -> Option<String> {
        // SAFETY: mj_id2name returns NULL or a pointer into the model's name buffer.
        let p = unsafe { ffi::mj_id2name(self.ptr.as_ptr(), kind.raw() as i32, id as i32) };
        if p.is_null() {
            None
        } else {
            // SAFETY: non-null, NUL-terminated, lives as long as the model.
            Some(unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
        }
    }

    /// Address in `qpos` of a joint's first coordinate.
    pub fn joint_qpos_addr(&self, joint: usize) -> usize {
        self.int_array(self.raw().jnt_qposadr, self.raw().njnt)[joint] as usize
    }

    /// Address in `qvel` of a joint's first degree of freedom.
    pub fn joint_dof_addr(&self, joint: usize) -> usize {
        self.int_array(self.raw().jnt_dofadr, self.raw().njnt)[joint] as usize
    }

    /// Address in `act` of an actuator's activation, if it has one. In 2.2.2 stateful
    /// actuators come last, so actuator i owns act[i - (nu - na)].
    pub fn actuator_act_addr(&self, actuator: usize) -> Option<usize> {
        let first_stateful = self.nu() - self.na();
        (actuator >= first_stateful && actuator < self.nu()).then(|| actuator - first_stateful)
    }

    /// Size parameters of a geom (radius first for spheres and cylinders).
    pub fn geom_size(&self, geom: usize) -> [f64; 3] {
        let all = self.num_array(self.raw().geom_size, self.raw().ngeom * 3);
        [all[3 * geom], all[3 * geom + 1], all[3 * geom + 2]]
    }

    /// The body a geom belongs to (`geom_bodyid`; 0 is the world body).
    pub fn geom_body(&self, geom: usize) -> usize {
        self.int_array(self.raw().geom_bodyid, self.raw().ngeom)[geom] as usize
    }

    /// Position of a geom in its body's frame (`geom_pos`).
    pub fn geom_pos(&self, geom: usize) -> [f64; 3] {
        let all = self.num_array(self.raw().geom_pos, self.raw().ngeom * 3);
        [all[3 * geom], all[3 * geom + 1], all[3 * geom + 2]]
    }

    /// Orientation of a geom in its body's frame (`geom_quat`).
    pub fn geom_quat(&self, geom: usize) -> [f64; 4] {
        let all = self.num_array(self.raw().geom_quat, self.raw().ngeom * 4);
        std::array::from_fn(|k| all[4 * geom + k])
    }

    /// Half-extents of a geom along its own axes, for the solid primitives (sphere, capsule,
    /// ellipsoid, cylinder, box); None for planes, height fields and meshes.
    pub fn geom_half_extents(&self, geom: usize) -> Option<[f64; 3]> {
        let kind = self.int_array(self.raw().geom_type, self.raw().ngeom)[geom];
        let [a, b, c] = self.geom_size(geom);
        // mjtGeom of 2.2.2: plane 0, hfield 1, sphere 2, capsule 3, ellipsoid 4, cylinder 5,
        // box 6, mesh 7.
        match kind {
            2 => Some([a, a, a]),
            3 => Some([a, a, a + b]),
            5 => Some([a, a, b]),
            4 | 6 => Some([a, b, c]),
            _ => None,
        }
    }

    /// Half extents of a box geom; None for every other kind.
    pub fn box_half_extents(&self, geom: usize) -> Option<[f64; 3]> {
        // mjtGeom of 2.2.2: box 6.
        let box_kind = self.int_array(self.raw().geom_type, self.raw().ngeom)[geom] == 6;
        box_kind.then(|| self.geom_size(geom))
    }

    /// A geom's contact bits (`[contype, conaffinity]`).
    pub fn geom_collision(&self, geom: usize) -> [i32; 2] {
        let n = self.raw().ngeom;
        [
            self.int_array(self.raw().geom_contype, n)[geom],
            self.int_array(self.raw().geom_conaffinity, n)[geom],
        ]
    }

    /// Sets a geom's contact bits (`[contype, conaffinity]`): `[0, 0]` takes it out of every
    /// contact.
    ///
    /// # Panics
    /// If `geom` is not a geom of the model.
    pub fn set_geom_collision(&mut self, geom: usize, bits: [i32; 2]) {
        let n = self.ngeom();
        assert!(geom < n, "geom {geom} of {n}");
        let m = self.raw();
        for (p, bit) in [(m.geom_contype, bits[0]), (m.geom_conaffinity, bits[1])] {
            // SAFETY: live model arrays of ngeom ints, uniquely borrowed through &mut self;
            // geom < ngeom.
            unsafe { *p.add(geom) = bit };
        }
    }

    /// The parent of a body (`body_parentid`; the world body is its own parent).
    pub fn body_parent(&self, body: usize) -> usize {
        self.int_array(self.raw().body_parentid, self.raw().nbody)[body] as usize
    }

    /// Number of bodies (the world body included).
    pub fn nbody(&self) -> usize {
        self.raw().nbody as usize
    }

    /// Mass of a body (kg).
    pub fn body_mass(&self, body: usize) -> f64 {
        self.num_array(self.raw().body_mass, self.raw().nbody)[body]
    }

    /// Principal moments of inertia of a body (kg m², in its inertial frame).
    pub fn body_inertia(&self, body: usize) -> [f64; 3] {
        let all = self.num_array(self.raw().body_inertia, self.raw().nbody * 3);
        [all[3 * body], all[3 * body + 1], all[3 * body + 2]]
    }

    /// Position of a body in its parent's frame (as written in the MJCF).
    pub fn body_pos(&self, body: usize) -> [f64; 3] {
        let all = self.num_array(self.raw().body_pos, self.raw().nbody * 3);
        [all[3 * body], all[3 * body + 1], all[3 * body + 2]]
    }

    /// Number of mocap bodies.
    pub fn nmocap(&self) -> usize {
        self.raw().nmocap as usize
    }

    /// The mocap index of a body (`body_mocapid`), if it is a mocap body.
    pub fn body_mocap_id(&self, body: usize) -> Option<usize> {
        let id = *self.int_array(self.raw().body_mocapid, self.raw().nbody).get(body)?;
        (id >= 0).then_some(id as usize)
    }

    /// Range of a joint, if it is limited.
    pub fn joint_range(&self, joint: usize) -> Option<[f64; 2]> {
        let m = self.raw();
        let limited = if m.njnt <= 0 || m.jnt_limited.is_null() {
            false
        } else {
            // SAFETY: jnt_limited holds njnt entries, alive with the model.
            let flags = unsafe { std::slice::from_raw_parts(m.jnt_limited, m.njnt as usize) };
            flags[joint] != 0
        };
        let all = self.num_array(m.jnt_range, m.njnt * 2);
        limited.then(|| [all[2 * joint], all[2 * joint + 1]])
    }

    /// The reference configuration `qpos0` (the model's pose as written in the MJCF).
    pub fn qpos0(&self) -> &[f64] {
        self.num_array(self.raw().qpos0, self.raw().nq)
    }

    /// Values of a `<custom><numeric>` field.
    pub fn numeric(&self, name: &str) -> Option<Vec<f64>> {
        let id = self.id(ObjKind::Numeric, name)?;
        let m = self.raw();
        let adr = self.int_array(m.numeric_adr, m.nnumeric)[id] as usize;
        let size = self.int_array(m.numeric_size, m.nnumeric)[id] as usize;
        let data = self.num_array(m.numeric_data, m.nnumericdata);
        Some(data[adr..adr + size].to_vec())
    }

    fn int_array(&self, p: *const i32, len: i32) -> &[i32] {
        if len <= 0 || p.is_null() {
            return &[];
        }
        // SAFETY: MuJoCo model arrays of the documented length, alive with the model.
        unsafe { std::slice::from_raw_parts(p, len as usize) }
    }

    fn num_array(&self, p: *const f64, len: i32) -> &[f64] {
        if len <= 0 || p.is_null() {
            return &[];
        }
        // SAFETY: as above.
        unsafe { std::slice::from_raw_parts(p, len as usize) }
    }
}

impl Drop for Model {
    fn drop(&mut self) {
        // SAFETY: we own the model; no Data outlives it (Simulation drops data first).
        unsafe { ffi::mj_deleteModel(self.ptr.as_ptr()) }
    }
}

/// One detected contact (after a step: the contacts of that step's collision phase).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    pub geom1: usize,
    pub geom2: usize,
    /// Signed distance; negative is penetration.
    pub dist: f64,
    pub pos: [f64; 3],
}

/// Read and write access to an `mjData` of known sizes: what the step wrapper hands to a
/// [`ControlHook`] and what [`Data`] offers outside a step.
pub struct DataView<'a> {
    d: &'a mut ffi::mjData,
    nq: usize,
    nv: usize,
    nu: usize,
    na: usize,
}

impl DataView<'_> {
    pub fn time(&self) -> f64 {
        self.d.time
    }
    pub fn qpos(&self) -> &[f64] {
        slice(self.d.qpos, self.nq)
    }
    pub fn qvel(&self) -> &[f64] {
        slice(self.d.qvel, self.nv)
    }
    pub fn act(&self) -> &[f64] {
        slice(self.d.act, self.na)
    }
    pub fn ctrl(&self) -> &[f64] {
        slice(self.d.ctrl, self.nu)
    }
    pub fn ctrl_mut(&mut self) -> &mut [f64] {
        slice_mut(self.d.ctrl, self.nu)
    }
}

fn slice<'a>(p: *const f64, len: usize) -> &'a [f64] {
    if len == 0 || p.is_null() {
        &[]
    } else {
        // SAFETY: mjData arrays of the model's sizes, alive while the view borrows the data.
        unsafe { std::slice::from_raw_parts(p, len) }
    }
}

fn slice_mut<'a>(p: *mut f64, len: usize) -> &'a mut [f64] {
    if len == 0 || p.is_null() {
        &mut []
    } else {
        // SAFETY: as above, and the view's &mut borrow makes this access unique.
        unsafe { std::slice::from_raw_parts_mut(p, len) }
    }
}

/// Simulation data (`mjData`) for one model, freed on drop.
pub struct Data {
    ptr: NonNull<ffi::mjData>,
    /// MuJoCo's error of a guarded call on it: the data is unusable (deleted when dropped,
    /// never reused).
    failed: Option<String>,
    nq: usize,
    nv: usize,
    nu: usize,
    na: usize,
    /// The model sizes it was laid out for: kept for reuse with them when dropped.
    sizes: Sizes,
}

// SAFETY: plain heap data owned by one episode at a time.
unsafe impl Send for Data {}

impl Data {
    /// `mj_makeData`, or this thread's spare data of a model with the same sizes, reset
    /// (`mj_resetData`).
    pub fn new(model: &Model) -> Result<Data, MjError> {
        let sizes = model.sizes();
        let spare = SPARE_DATA
            .try_with(|cell| {
                let mut slot = cell.borrow_mut();
                match &*slot {
                    Some(spare) if spare.sizes == sizes => slot.take(),
                    _ => None,
                }
            })
            .ok()
            .flatten();
        let ptr = match spare {
            Some(spare) => {
                let ptr = spare.into_ptr();
                // SAFETY: data laid out for a model of these sizes, now owned here;
                // mj_resetData sets every field from `model` as mj_makeData does.
                unsafe { ffi::mj_resetData(model.ptr.as_ptr(), ptr.as_ptr()) };
                ptr
            }
            None => {
                #[cfg(test)]
                tests::MADE.with(|n| n.set(n.get() + 1));
                // SAFETY: live model.
                let raw = unsafe { ffi::mj_makeData(model.ptr.as_ptr()) };
                NonNull::new(raw).ok_or(MjError::DataAllocation)?
            }
        };
        Ok(Data {
            ptr,
            nq: model.nq(),
            nv: model.nv(),
            nu: model.nu(),
            na: model.na(),
            sizes,
            failed: None,
        })
    }

    pub fn view(&mut self) -> DataView<'_> {
        DataView {
            // SAFETY: live data, uniquely borrowed through &mut self.
            d: unsafe { self.ptr.as_mut() },
            nq: self.nq,
            nv: self.nv,
            nu: self.nu,
            na: self.na,
        }
    }

    fn raw(&self) -> &ffi::mjData {
        // SAFETY: live data owned by self.
        unsafe { self.ptr.as_ref() }
    }

    pub fn time(&self) -> f64 {
        self.raw().time
    }
    pub fn qpos(&self) -> &[f64] {
        slice(self.raw().qpos, self.nq)
    }
    pub fn qvel(&self) -> &[f64] {
        slice(self.raw().qvel, self.nv)
    }
    pub fn act(&self) -> &[f64] {
        slice(self.raw().act, self.na)
    }
    pub fn ctrl(&self) -> &[f64] {
        slice(self.raw().ctrl, self.nu)
    }

    /// Contacts found by the last collision phase.
    pub fn contacts(&self) -> Vec<Contact> {
        let d = self.raw();
        let n = d.ncon.max(0) as usize;
        if n == 0 || d.contact.is_null() {
            return Vec::new();
        }
        // SAFETY: d.contact holds at least ncon entries.
        let raw = unsafe { std::slice::from_raw_parts(d.contact, n) };
        raw.iter()
            .map(|c| Contact {
                geom1: c.geom1 as usize,
                geom2: c.geom2 as usize,
                dist: c.dist,
                pos: c.pos,
            })
            .collect()
    }

    /// How often MuJoCo raised each warning so far (`mjData.warning[i].number`).
    fn warning_counts(&self) -> [i32; NWARNING] {
        self.raw().warning.map(|w| w.number)
    }

    /// `mjData.warning[i].lastinfo`: the size or index MuJoCo reported with the warning.
    fn warning_info(&self, warning: ffi::mjtWarning) -> i32 {
        self.raw().warning[warning as usize].lastinfo
    }
}

const NWARNING: usize = ffi::mjtWarning::mjNWARNING as usize;

/// MuJoCo's "bad number" warnings (qpos, qvel, qacc, ctrl): the step reports them as errors.
const BAD_NUMBERS: [(ffi::mjtWarning, &str); 4] = [
    (ffi::mjtWarning::mjWARN_BADQPOS, "qpos"),
    (ffi::mjtWarning::mjWARN_BADQVEL, "qvel"),
    (ffi::mjtWarning::mjWARN_BADQACC, "qacc"),
    (ffi::mjtWarning::mjWARN_BADCTRL, "ctrl"),
];

/// The warnings after which the step went on with physics other than the model's (contacts or
/// constraints dropped, a near-singular inertia): reported once each, the run goes on.
/// (`mjWARN_VGEOMFULL` is visualisation only.)
const DEGRADING: [ffi::mjtWarning; 3] = [
    ffi::mjtWarning::mjWARN_CONTACTFULL,
    ffi::mjtWarning::mjWARN_CNSTRFULL,
    ffi::mjtWarning::mjWARN_INERTIA,
];

/// A MuJoCo warning after which the simulated physics is not what the model describes.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicsWarning {
    /// Short name, e.g. `contact_buffer_full`.
    pub name: &'static str,
    /// What happened and the model attribute to change.
    pub message: String,
}

impl Drop for Data {
    fn drop(&mut self) {
        if self.failed.is_some() {
            // SAFETY: owned, and never used again.
            unsafe { ffi::mj_deleteData(self.ptr.as_ptr()) };
            return;
        }
        let spare = SpareData {
            sizes: self.sizes,
            ptr: self.ptr,
        };
        // The one it replaces is deleted after the slot is released; at thread exit (slot
        // gone) the closure is dropped unrun, and with it `spare`.
        let replaced = SPARE_DATA.try_with(move |cell| cell.borrow_mut().replace(spare));
        drop(replaced);
    }
}

/// Where a `mjcb_control` call falls inside the current `mj_step`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CallbackContext {
    /// Step counter set by [`Simulation::step`]: the step being taken is `step → step + 1`.
    pub step: u64,
    /// 0 for the call at the real state (start of the step), 1.. for RK4's trial stages.
    pub call_in_step: u32,
    /// `d->time` at the call.
    pub time: f64,
    /// `d->time` when the step began (so `time − step_start_time` is the stage offset).
    pub step_start_time: f64,
}

/// Receives every `mjcb_control` call fired while [`Simulation::step`] runs on this thread.
pub trait ControlHook {
    /// Must only write `ctrl` (RK4 calls this at trial states).
    fn on_control(&mut self, ctx: CallbackContext, data: &mut DataView<'_>);
}

struct ActiveHook {
    hook: *mut (dyn ControlHook + 'static),
    step: u64,
    step_start_time: f64,
    calls: u32,
    nq: usize,
    nv: usize,
    nu: usize,
    na: usize,
}

thread_local! {
    /// The hook of the episode stepping on this thread, set only for the duration of a step.
    static ACTIVE: RefCell<Option<ActiveHook>> = const { RefCell::new(None) };
    /// The message of a panic caught inside the callback during the current step.
    static CAUGHT_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

static INSTALL: Once = Once::new();

fn install_callback() {
    INSTALL.call_once(|| {
        // SAFETY: writing MuJoCo's global callback and handler pointers once, before any
        // model is loaded or stepped.
        unsafe {
            ffi::mjcb_control = Some(control_trampoline);
            ffi::mju_user_warning = Some(warning_handler);
            ffi::mju_user_error = Some(mjsafe_error_handler);
        }
    });
}

thread_local! {
    /// The last MuJoCo warning raised on this thread (the handler keeps it instead of letting
    /// MuJoCo print it and append it to `MUJOCO_LOG.TXT` in the working directory).
    static LAST_WARNING: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// The last MuJoCo warning raised on this thread, if any since the last call.
pub fn take_warning() -> Option<String> {
    LAST_WARNING.with(|w| w.borrow_mut().take())
}

/// `mju_user_warning`: keeps the text for the step that raised it (which reports the
/// warning as its error, see [`Simulation::step`]).
unsafe extern "C" fn warning_handler(message: *const std::os::raw::c_char) {
    let _ = catch_unwind(|| {
        // SAFETY: MuJoCo passes a NUL-terminated message.
        let text = unsafe { CStr::from_ptr(message) }.to_string_lossy().trim().to_string();
        LAST_WARNING.with(|w| *w.borrow_mut() = Some(text));
    });
}

/// MuJoCo's error outside a guarded step or forward pass ([`mjsafe_guarded`]: `mj_makeData`,
/// say), where no run can be ended alone. MuJoCo 2.2.2's `mju_error` returns to its caller
/// when the handler returns (and without a handler prints, waits for Enter and exits), so this
/// never returns: it prints one error line, removes the `.partial` outputs, and exits with 1.
/// The model compiler installs its own (thread-local) handler, so XML and compile errors
/// still come back as [`MjError::Load`].
#[unsafe(no_mangle)]
unsafe extern "C" fn mjsafe_fatal_error(message: *const std::os::raw::c_char) {
    let _ = catch_unwind(|| {
        // SAFETY: MuJoCo passes a NUL-terminated message.
        let text = unsafe { CStr::from_ptr(message) }.to_string_lossy().trim().to_string();
        eprintln!("error: MuJoCo stopped the run: {text} (no log was finished)");
        crate::files::remove_partials();
    });
    std::process::exit(1);
}

/// Runs `mj_step` (or `mj_forward`) of `data` behind [`mjsafe_guarded`]: MuJoCo's error comes
/// back as its message, and `data` is marked unusable.
fn guarded(model: &Model, data: &mut Data, forward: bool) -> Result<(), String> {
    if let Some(message) = &data.failed {
        return Err(format!("{message} (an earlier call; the data is unusable)"));
    }
    // SAFETY: live model and data of that model.
    let failed = unsafe { mjsafe_guarded(model.ptr.as_ptr(), data.ptr.as_ptr(), forward.into()) };
    if failed == 0 {
        return Ok(());
    }
    // SAFETY: the shim's per-thread NUL-terminated message of the error just caught.
    let message = unsafe { CStr::from_ptr(mjsafe_error_message()) }
        .to_string_lossy()
        .trim()
        .to_string();
    data.failed = Some(message.clone());
    Err(message)
}

/// The process-wide `mjcb_control`: dispatches to the current thread's hook; catches panics.
unsafe extern "C" fn control_trampoline(_m: *const ffi::mjModel, d: *mut ffi::mjData) {
    // SAFETY: plain thread-local counters of the shim (no MuJoCo error jumps over this frame).
    unsafe { mjsafe_enter_rust() };
    let result = catch_unwind(AssertUnwindSafe(|| {
        ACTIVE.with(|cell| {
            let mut active = cell.borrow_mut();
            let Some(active) = active.as_mut() else {
                return; // mj_forward outside a step, or another thread's plain MuJoCo use.
            };
            if CAUGHT_PANIC.with(|m| m.borrow().is_some()) {
                return; // an earlier stage of this step panicked: leave ctrl as it is.
            }
            // SAFETY: MuJoCo passes the live mjData being stepped.
            let d = unsafe { &mut *d };
            let ctx = CallbackContext {
                step: active.step,
                call_in_step: active.calls,
                time: d.time,
                step_start_time: active.step_start_time,
            };
            active.calls += 1;
            let mut view = DataView {
                d,
                nq: active.nq,
                nv: active.nv,
                nu: active.nu,
                na: active.na,
            };
            // SAFETY: the hook pointer is valid for the duration of Simulation::step,
            // which is the only time ACTIVE is Some.
            let hook = unsafe { &mut *active.hook };
            hook.on_control(ctx, &mut view);
        })
    }));
    if let Err(payload) = result {
        let message = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "non-string panic payload".to_string());
        CAUGHT_PANIC.with(|m| *m.borrow_mut() = Some(message));
    }
    // SAFETY: as above.
    unsafe { mjsafe_leave_rust() };
}

/// A model with its data: the thing that steps.
pub struct Simulation {
    // Field order matters: data is dropped before the model it was made from.
    data: Data,
    model: Model,
    step: u64,
    /// Bit i: warning i of [`DEGRADING`] was raised (set once) / not yet taken.
    raised: u8,
    pending: u8,
    /// Start time of the step that first raised each.
    raised_at: [f64; DEGRADING.len()],
}

impl Simulation {
    pub fn new(model: Model) -> Result<Simulation, MjError> {
        let data = Data::new(&model)?;
        Ok(Simulation {
            data,
            model,
            step: 0,
            raised: 0,
            pending: 0,
            raised_at: [0.0; DEGRADING.len()],
        })
    }

    pub fn model(&self) -> &Model {
        &self.model
    }
    pub fn data(&self) -> &Data {
        &self.data
    }

    /// Steps taken so far.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// Sets time, qpos, qvel and act (the full state) and recomputes derived quantities
    /// with `mj_forward` (no hook is active, so the control callback does nothing).
    pub fn set_state(&mut self, time: f64, qpos: &[f64], qvel: &[f64], act: &[f64]) {
        {
            let v = self.data.view();
            v.d.time = time;
            slice_mut(v.d.qpos, v.nq).copy_from_slice(qpos);
            slice_mut(v.d.qvel, v.nv).copy_from_slice(qvel);
            slice_mut(v.d.act, v.na).copy_from_slice(act);
        }
        // A MuJoCo error here marks the data unusable: the next step reports it.
        let _ = guarded(&self.model, &mut self.data, true);
    }

    /// One `mj_step`, with `hook` receiving every control callback of the step.
    /// A panic inside the hook is caught in the callback and returned here as an error;
    /// so is any MuJoCo "bad number" warning (MuJoCo would silently reset the state). The
    /// first of each warning that changes the physics is kept for [`Simulation::take_warning`].
    pub fn step(&mut self, hook: &mut dyn ControlHook) -> Result<(), MjError> {
        let warnings_before = self.data.warning_counts();
        let start_time = self.data.time();
        // SAFETY (lifetime erasure): the pointer is removed from ACTIVE before this function
        // returns, so it never outlives `hook`.
        let hook_ptr: *mut (dyn ControlHook + '_) = hook;
        let hook_ptr: *mut (dyn ControlHook + 'static) = unsafe { std::mem::transmute(hook_ptr) };
        ACTIVE.with(|cell| {
            *cell.borrow_mut() = Some(ActiveHook {
                hook: hook_ptr,
                step: self.step,
                step_start_time: start_time,
                calls: 0,
                nq: self.data.nq,
                nv: self.data.nv,
                nu: self.data.nu,
                na: self.data.na,
            })
        });
        let stepped = guarded(&self.model, &mut self.data, false);
        ACTIVE.with(|cell| *cell.borrow_mut() = None);
        self.step += 1;
        if let Err(message) = stepped {
            CAUGHT_PANIC.with(|m| m.borrow_mut().take());
            return Err(MjError::Runtime {
                time: start_time,
                message,
            });
        }
        if let Some(message) = CAUGHT_PANIC.with(|m| m.borrow_mut().take()) {
            return Err(MjError::CallbackPanicked {
                time: start_time,
                message,
            });
        }
        let warnings_after = self.data.warning_counts();
        for (warning, what) in BAD_NUMBERS {
            if warnings_after[warning as usize] > warnings_before[warning as usize] {
                return Err(MjError::Unstable {
                    time: start_time,
                    message: format!(
                        "NaN, Inf or huge value in {what}; MuJoCo reset the state, so the episode stops{}",
                        // MuJoCo's text, kept from its log file and stdout.
                        take_warning().map_or(String::new(), |w| format!(" (MuJoCo: {w})"))
                    ),
                });
            }
        }
        for (i, warning) in DEGRADING.iter().enumerate() {
            let bit = 1 << i;
            if self.raised & bit == 0 && warnings_after[*warning as usize] > warnings_before[*warning as usize] {
                self.raised |= bit;
                self.pending |= bit;
                self.raised_at[i] = start_time;
            }
        }
        Ok(())
    }

    /// A warning that changed the physics, raised by a step since the last call: each kind
    /// once per simulation, the first time it occurs.
    pub fn take_warning(&mut self) -> Option<PhysicsWarning> {
        if self.pending == 0 {
            return None;
        }
        let i = self.pending.trailing_zeros() as usize;
        self.pending &= !(1 << i);
        let warning = DEGRADING[i];
        let info = self.data.warning_info(warning);
        let at = format!("at t = {} s", self.raised_at[i]);
        let m = self.model.raw();
        let size = |attribute: &str, value: i32| {
            if value >= 0 {
                format!("({attribute} = {value}): raise {attribute} in the model's <size>")
            } else {
                format!("({attribute} unset, the buffer comes from nstack = {}): raise nstack or set {attribute} in the model's <size>", m.nstack)
            }
        };
        let (name, message) = match warning {
            ffi::mjtWarning::mjWARN_CONTACTFULL => (
                "contact_buffer_full",
                format!("contact buffer full {at} {}; contacts beyond it were dropped", size("nconmax", m.nconmax)),
            ),
            ffi::mjtWarning::mjWARN_CNSTRFULL => (
                "constraint_buffer_full",
                format!("constraint buffer full {at} {}; constraints beyond it were dropped", size("njmax", m.njmax)),
            ),
            _ => (
                "inertia_singular",
                format!("inertia matrix too close to singular {at} (dof {info}): raise the model's masses, inertias or armature"),
            ),
        };
        // MuJoCo's own text is not added: the thread keeps only its last warning, which may be
        // another kind raised in the same step; the message above says all it says.
        Some(PhysicsWarning { name, message })
    }

    /// World position of a geom (`geom_xpos`) as the last kinematics computed it (after
    /// `mj_step`: the state the step started from).
    ///
    /// # Panics
    /// If `geom` is not a geom of the model.
    pub fn geom_xpos(&self, geom: usize) -> [f64; 3] {
        let n = self.model.ngeom();
        assert!(geom < n, "geom {geom} of {n}");
        let all = slice(self.data.raw().geom_xpos, 3 * n);
        [all[3 * geom], all[3 * geom + 1], all[3 * geom + 2]]
    }

    /// World orientation of a geom (`geom_xmat`, row-major: its columns are the geom's axes) as
    /// the last kinematics computed it.
    ///
    /// # Panics
    /// If `geom` is not a geom of the model.
    pub fn geom_xmat(&self, geom: usize) -> [f64; 9] {
        let n = self.model.ngeom();
        assert!(geom < n, "geom {geom} of {n}");
        let all = slice(self.data.raw().geom_xmat, 9 * n);
        std::array::from_fn(|k| all[9 * geom + k])
    }

    /// Sets the position of mocap body `mocap` (`mocap_pos`): where the next step's
    /// kinematics and collision place it.
    ///
    /// # Panics
    /// If `mocap` is not below the model's `nmocap`.
    pub fn set_mocap_pos(&mut self, mocap: usize, position: [f64; 3]) {
        let n = self.model.nmocap();
        assert!(mocap < n, "mocap body {mocap} of {n}");
        let v = self.data.view();
        slice_mut(v.d.mocap_pos, 3 * n)[3 * mocap..3 * mocap + 3].copy_from_slice(&position);
    }

    /// Sets mocap body `mocap`'s orientation to the turn `yaw` (rad) about the vertical axis.
    ///
    /// # Panics
    /// If `mocap` is not below the model's `nmocap`.
    pub fn set_mocap_yaw(&mut self, mocap: usize, yaw: f64) {
        let n = self.model.nmocap();
        assert!(mocap < n, "mocap body {mocap} of {n}");
        let (s, c) = (0.5 * yaw).sin_cos();
        let v = self.data.view();
        slice_mut(v.d.mocap_quat, 4 * n)[4 * mocap..4 * mocap + 4].copy_from_slice(&[c, 0.0, 0.0, s]);
    }

    /// Places world-body geom `geom` where a mocap body at `position` with orientation
    /// `body_quat` would place a geom at its origin with the local orientation `local`, for the
    /// next step's kinematics and collision (its `geom_pos` and `geom_quat` in the model): the
    /// same `geom_xpos` bit for bit and `geom_xmat` to rounding (MuJoCo's own normalisation and
    /// quaternion product); a world geom is no body of the implicit integrator's derivatives,
    /// which a mocap body is.
    ///
    /// # Panics
    /// If `geom` is not below the model's `ngeom` or is not the world body's.
    pub fn place_world_geom(&mut self, geom: usize, position: [f64; 3], body_quat: [f64; 4], local: [f64; 4]) {
        let n = self.model.ngeom();
        assert!(geom < n, "geom {geom} of {n}");
        assert_eq!(self.model.geom_body(geom), 0, "geom {geom} is not the world body's");
        let (mut body, mut quat) = (body_quat, [0.0; 4]);
        // SAFETY: MuJoCo's pure quaternion functions on arrays of four on this stack frame.
        unsafe {
            ffi::mju_normalize4(body.as_mut_ptr());
            ffi::mju_mulQuat(quat.as_mut_ptr(), body.as_ptr(), local.as_ptr());
        }
        let m = self.model.ptr.as_ptr();
        // SAFETY: the model's geom arrays have ngeom entries (3, 4 and 1 per geom); no step runs
        // while `self` is borrowed mutably, and MuJoCo reads them only inside a step.
        unsafe {
            slice_mut((*m).geom_pos, 3 * n)[3 * geom..3 * geom + 3].copy_from_slice(&position);
            slice_mut((*m).geom_quat, 4 * n)[4 * geom..4 * geom + 4].copy_from_slice(&quat);
            *(*m).geom_sameframe.add(geom) = 0;
        }
    }

    /// Sets `ctrl` (outside a step; the hook sets it during steps).
    pub fn set_ctrl(&mut self, ctrl: &[f64]) {
        let v = self.data.view();
        slice_mut(v.d.ctrl, v.nu).copy_from_slice(ctrl);
    }

    /// One `mj_step` with no hook: the control callback returns at once and `ctrl` keeps its
    /// value (the bare physics loop benchmarks compare against).
    pub fn step_without_hook(&mut self) -> Result<(), MjError> {
        let time = self.data.time();
        self.step += 1;
        guarded(&self.model, &mut self.data, false).map_err(|message| MjError::Runtime { time, message })
    }

    /// Calls `mj_forward` (fires the callback only if a hook is active: never here). A MuJoCo
    /// error marks the data unusable: the next step reports it.
    pub fn forward(&mut self) {
        let _ = guarded(&self.model, &mut self.data, true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    thread_local! {
        /// `mj_loadXML` calls on this thread.
        pub(super) static COMPILES: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
        /// `mj_makeData` calls on this thread for a simulation.
        pub(super) static MADE: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    }

    const SLIDER: &str = r#"<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="cart" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0"/>
      <geom type="box" size="0.2 0.1 0.1" mass="2" contype="0" conaffinity="0"/>
    </body>
    <body name="ball" pos="0.5 0 0.3">
      <freejoint/>
      <geom type="sphere" size="0.05" mass="0.1"/>
    </body>
  </worldbody>
  <actuator><motor joint="x" name="push"/></actuator>
</mujoco>"#;

    fn compiles() -> usize {
        COMPILES.with(|n| n.get())
    }

    fn made() -> usize {
        MADE.with(|n| n.get())
    }

    /// qpos and qvel after 200 steps with a constant push (the ball lands on the floor and
    /// stays in contact).
    fn trajectory(model: Model) -> (Vec<f64>, Vec<f64>) {
        let mut sim = Simulation::new(model).unwrap();
        sim.set_ctrl(&[1.5]);
        for _ in 0..200 {
            sim.step_without_hook().unwrap();
        }
        assert!(!sim.data().contacts().is_empty(), "the ball rests on the floor");
        (sim.data().qpos().to_vec(), sim.data().qvel().to_vec())
    }

    /// A probe on a slider and a mocap sphere that only the probe's geom collides with.
    const MOCAP: &str = r#"<mujoco>
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody>
    <body name="probe">
      <joint name="x" type="slide" axis="1 0 0"/>
      <geom name="hull" type="sphere" size="1" mass="1" contype="1" conaffinity="0"/>
    </body>
    <body name="actor" mocap="true" pos="10 0 0">
      <geom name="actor" type="sphere" size="1" contype="0" conaffinity="1"/>
    </body>
  </worldbody>
</mujoco>"#;

    /// The same turned box twice: in a mocap body, and as a geom of the world body.
    const TWO_BOXES: &str = r#"<mujoco>
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody>
    <body name="probe">
      <joint name="x" type="slide" axis="1 0 0"/>
      <geom name="hull" type="box" size="1 0.5 0.5" mass="1" contype="1" conaffinity="0"/>
    </body>
    <body name="actor" mocap="true" pos="10 0 0">
      <geom name="in_body" type="box" size="2 1 2" quat="0.9 0 0 0.43589" contype="0" conaffinity="1"/>
    </body>
    <geom name="in_world" type="box" size="2 1 2" quat="0.9 0 0 0.43589" pos="10 0 0" contype="0" conaffinity="1"/>
  </worldbody>
</mujoco>"#;

    /// A world geom placed as a mocap body would place it has that geom's position bit for bit
    /// and its orientation to rounding (MuJoCo turns a body's geom by the body's matrix, a world
    /// geom by its quaternion's), and the contacts see it.
    #[test]
    fn a_placed_world_geom_is_where_the_mocap_body_puts_its_geom() {
        let model = Model::from_xml_string(TWO_BOXES, "two boxes").unwrap();
        let (in_body, in_world, hull) = (
            model.require(ObjKind::Geom, "in_body").unwrap(),
            model.require(ObjKind::Geom, "in_world").unwrap(),
            model.require(ObjKind::Geom, "hull").unwrap(),
        );
        let local = model.geom_quat(in_world);
        assert_eq!(local, model.geom_quat(in_body));
        let mut sim = Simulation::new(model).unwrap();
        for (k, (x, y, yaw)) in [(1.9, -0.2, 0.3), (-1.75, 1e-3, -2.9), (0.4, 0.1, 1.234_567)]
            .into_iter()
            .enumerate()
        {
            sim.set_mocap_pos(0, [x, y, 0.0]);
            sim.set_mocap_yaw(0, yaw);
            let (s, c) = (0.5 * yaw).sin_cos();
            sim.place_world_geom(in_world, [x, y, 0.0], [c, 0.0, 0.0, s], local);
            sim.step_without_hook().unwrap();
            assert_eq!(sim.geom_xpos(in_world), sim.geom_xpos(in_body), "pose {k}");
            let (a, b) = (sim.geom_xmat(in_world), sim.geom_xmat(in_body));
            assert!(
                a.iter().zip(&b).all(|(a, b)| (a - b).abs() <= 1e-15),
                "pose {k}: {a:?} against {b:?}"
            );
            let touching = |geom: usize| {
                sim.data()
                    .contacts()
                    .iter()
                    .any(|c| [c.geom1, c.geom2] == [hull, geom] || [c.geom1, c.geom2] == [geom, hull])
            };
            assert!(
                touching(in_world) && touching(in_body),
                "pose {k}: both boxes overlap the probe"
            );
        }
    }

    #[test]
    fn a_mocap_body_is_where_it_was_set_when_the_step_collides() {
        let model = Model::from_xml_string(MOCAP, "mocap").unwrap();
        let actor = model.require(ObjKind::Body, "actor").unwrap();
        let probe = model.require(ObjKind::Body, "probe").unwrap();
        assert_eq!((model.nmocap(), model.body_mocap_id(actor)), (1, Some(0)));
        assert_eq!(model.body_mocap_id(probe), None);
        assert_eq!(model.body_mocap_id(99), None);
        let (hull, geom) = (
            model.require(ObjKind::Geom, "hull").unwrap(),
            model.require(ObjKind::Geom, "actor").unwrap(),
        );
        let mut sim = Simulation::new(model).unwrap();
        sim.step_without_hook().unwrap();
        assert_eq!(sim.geom_xpos(geom), [10.0, 0.0, 0.0]);
        assert!(sim.data().contacts().is_empty());
        // Moved into the probe: that step's kinematics and contacts have it there.
        sim.set_mocap_pos(0, [1.5, 0.25, 0.0]);
        sim.step_without_hook().unwrap();
        assert_eq!(sim.geom_xpos(geom), [1.5, 0.25, 0.0]);
        let contacts = sim.data().contacts();
        let touch = contacts
            .iter()
            .find(|c| (c.geom1, c.geom2) == (hull, geom) || (c.geom1, c.geom2) == (geom, hull))
            .expect("the probe touches the moved sphere");
        let expected = 2.0 - 1.5f64.hypot(0.25);
        assert!((-touch.dist - expected).abs() < 1e-9, "{touch:?}");
        // And out again.
        sim.set_mocap_pos(0, [-5.0, 0.0, 0.0]);
        sim.step_without_hook().unwrap();
        assert_eq!(sim.geom_xpos(geom), [-5.0, 0.0, 0.0]);
        assert!(sim.data().contacts().is_empty());
    }

    #[test]
    #[should_panic(expected = "mocap body 1 of 1")]
    fn a_mocap_index_out_of_range_is_refused() {
        let mut sim = Simulation::new(Model::from_xml_string(MOCAP, "mocap").unwrap()).unwrap();
        sim.set_mocap_pos(1, [0.0; 3]);
    }

    #[test]
    fn text_naming_another_file_is_recognised() {
        for xml in [
            r#"<mesh file="hull.stl"/>"#,
            r#"<texture fileright = "r.png"/>"#,
            "<include file='parts.xml'/>",
            r#"<hfield name="h" file="h.png"/>"#,
            "<!-- file= in a comment counts too -->",
        ] {
            assert!(names_other_files(xml), "{xml}");
        }
        for xml in [
            SLIDER,
            "<!-- this file is the plant only -->",
            "<geom name=\"profile\"/>",
        ] {
            assert!(!names_other_files(xml), "{xml}");
        }
        for model in [
            "bicycle",
            "car",
            "unicycle",
            "double_integrator_1d",
            "double_integrator_2d",
            "longitudinal",
        ] {
            let path = format!("{}/models/{model}.xml", env!("CARGO_MANIFEST_DIR"));
            assert!(!names_other_files(&std::fs::read_to_string(&path).unwrap()), "{path}");
        }
    }

    #[test]
    fn the_same_text_is_compiled_once_per_thread_and_its_copies_are_the_model() {
        // A thread of its own: the cache and the counter start empty.
        std::thread::spawn(|| {
            let fresh = Model::from_xml_string(SLIDER, "slider").unwrap();
            assert_eq!(compiles(), 1);
            let mut copy = Model::from_xml_string(SLIDER, "slider").unwrap();
            assert_eq!(compiles(), 1, "served from the cache");
            assert_eq!((copy.nq(), copy.nv(), copy.nu()), (fresh.nq(), fresh.nv(), fresh.nu()));
            assert_eq!(copy.timestep(), 0.002);
            // A change to a served copy stays in that copy.
            copy.set_timestep(0.01);
            let again = Model::from_xml_string(SLIDER, "slider").unwrap();
            assert_eq!(again.timestep(), 0.002);
            // The copy steps bit for bit as the compiled model, on the first run's mjData
            // (reset, not allocated again).
            let expected = trajectory(fresh);
            assert!(expected.0[0] > 0.01, "{expected:?}");
            assert_eq!(made(), 1);
            assert_eq!(trajectory(again), expected);
            assert_eq!(made(), 1, "the spare mjData was reused");
            let twice = Model::from_xml_string(SLIDER, "slider").unwrap();
            assert_eq!(trajectory(twice), expected);
            assert_eq!(made(), 1);
            // Other text is compiled (and joins the two cached ones); text naming a file always is.
            let other = SLIDER.replace("mass=\"2\"", "mass=\"3\"");
            let heavier = Model::from_xml_string(&other, "slider").unwrap();
            assert_eq!(compiles(), 2);
            assert!(trajectory(heavier).0[0] < expected.0[0]);
            assert_eq!(made(), 1, "another mass, the same sizes: the same mjData");
            // A model compiled anew with the same sizes steps the same on it.
            let direct = Model::compile(SLIDER, "slider").unwrap();
            assert_eq!(trajectory(direct), expected);
            assert_eq!(made(), 1);
            // The last two texts are both served (the bare and the full model of a footprint).
            let copies = [&other, SLIDER, &other].map(|t| Model::from_xml_string(t, "slider").unwrap());
            assert_eq!(compiles(), 3, "{} copies served from the cache", copies.len());
            // Other sizes get their own mjData; the spare is the last one dropped.
            let with_site = SLIDER.replace("<freejoint/>", "<freejoint/><site name=\"s\"/>");
            let sited = trajectory(Model::from_xml_string(&with_site, "slider").unwrap());
            assert_eq!(sited, expected, "a site changes the sizes, not the motion");
            assert_eq!(made(), 2);
            assert_eq!(trajectory(Model::from_xml_string(SLIDER, "slider").unwrap()), expected);
            assert_eq!(made(), 3);
            let naming = format!("{SLIDER}<!-- file= -->");
            Model::from_xml_string(&naming, "slider").unwrap();
            Model::from_xml_string(&naming, "slider").unwrap();
            assert_eq!(compiles(), 7);
            // Errors are not cached, and are one line.
            for _ in 0..2 {
                let e = Model::from_xml_string("<mujoco><bad/></mujoco>", "broken")
                    .err()
                    .unwrap();
                assert!(e.to_string().contains("broken"), "{e}");
                let missing = SLIDER.replace(
                    "<worldbody>",
                    "<asset><mesh name=\"m\" file=\"missing.stl\"/></asset><worldbody>",
                );
                let e = Model::from_xml_string(&missing, "meshed").err().unwrap().to_string();
                assert!(
                    e.contains("missing.stl") && e.contains("line = ") && !e.contains('\n'),
                    "{e}"
                );
            }
            assert_eq!(compiles(), 11);
        })
        .join()
        .unwrap();
    }
}
