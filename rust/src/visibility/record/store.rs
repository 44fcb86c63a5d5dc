//! The packed layout of records (CAM08 §5.5; the memory table of the module docs of
//! [`super`]): a [`RecordStore`] keeps every record of one resolution as a 36-byte
//! [`RecordHeader`] plus `words_per_map(M)` `u64` words (bits, then hierarchy codes) in two
//! flat arrays, with no per-record pointers or allocations.

use super::*;

/// The fixed part of a packed record (36 bytes, module docs): quantised normal and `A`,
/// `f32` position and `R_i`, `u32` counters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct RecordHeader {
    /// Position, world units.
    pub position: [f32; 3],
    /// Normal as equal-area square coordinates, each `round(65535 · u)`.
    normal: [u16; 2],
    /// `R_i`, world units (`inf`: nothing hit).
    pub nearest_hit_distance: f32,
    /// See [`Record::misses`].
    pub misses: u32,
    /// See [`Record::uses`].
    pub uses: u32,
    /// See [`Record::last_frame`].
    pub last_frame: u32,
    /// `A` in units of 1/65535.
    ambient_occlusion: u16,
    _reserved: u16,
}

const _: () = assert!(std::mem::size_of::<RecordHeader>() == 36);

impl RecordHeader {
    fn pack(r: &Record) -> Self {
        let q = |x: f32| (x.clamp(0.0, 1.0) * 65535.0).round() as u16;
        let s = sphere_to_square(r.normal);
        Self {
            position: r.position.to_array(),
            normal: [q(s.x), q(s.y)],
            nearest_hit_distance: r.nearest_hit_distance,
            misses: r.misses,
            uses: r.uses,
            last_frame: r.last_frame,
            ambient_occlusion: q(r.ambient_occlusion),
            _reserved: 0,
        }
    }

    /// A header from its stored fields (as [`Self::quantised`] returns them).
    pub fn from_quantised(
        position: [f32; 3],
        normal: [u16; 2],
        nearest_hit_distance: f32,
        counters: [u32; 3],
        ambient_occlusion: u16,
    ) -> Self {
        Self {
            position,
            normal,
            nearest_hit_distance,
            misses: counters[0],
            uses: counters[1],
            last_frame: counters[2],
            ambient_occlusion,
            _reserved: 0,
        }
    }

    /// The quantised normal (equal-area square coordinates in units of 1/65535) and `A`
    /// (units of 1/65535), exactly as stored.
    pub fn quantised(&self) -> ([u16; 2], u16) {
        (self.normal, self.ambient_occlusion)
    }

    /// Position, world units.
    pub fn position(&self) -> Vec3 {
        Vec3::from(self.position)
    }

    /// Unit normal, decoded (within 1e-4 rad of the stored one).
    pub fn normal(&self) -> Vec3 {
        let s = Vec2::new(self.normal[0] as f32, self.normal[1] as f32) / 65535.0;
        square_to_sphere(s).normalize()
    }

    /// Ambient occlusion in `[0, 1]`, within 1/131070 of the stored one.
    pub fn ambient_occlusion(&self) -> f32 {
        self.ambient_occlusion as f32 / 65535.0
    }
}

/// Records of one resolution, packed ([`bytes_per_record`] bytes each, no per-record
/// allocation): headers in one array, map words (bits then codes) in another, record `i`
/// at words `i · words_per_map(M) ..`. Indices are dense; [`RecordStore::swap_remove`]
/// moves the last record into the hole.
#[derive(Clone, Debug, Default)]
pub struct RecordStore {
    m: u32,
    pub(super) headers: Vec<RecordHeader>,
    pub(super) words: Vec<u64>,
}

impl RecordStore {
    /// An empty store for `2^m x 2^m` records. Fails for `m` outside `1..=7`.
    pub fn new(m: u32) -> Result<Self> {
        check_log2_resolution(m)?;
        Ok(Self {
            m,
            headers: Vec::new(),
            words: Vec::new(),
        })
    }

    /// Resolution exponent of every record.
    pub fn m(&self) -> u32 {
        self.m
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.headers.len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.headers.is_empty()
    }

    /// Appends a record (quantising normal and `A`) and returns its index. Fails when the
    /// record's resolution is not the store's.
    pub fn push(&mut self, r: &Record) -> Result<usize> {
        if r.bits.m() != self.m {
            return Err(Error::invalid(
                "record",
                format!(
                    "has resolution 2^{} but the store holds 2^{} records",
                    r.bits.m(),
                    self.m
                ),
            ));
        }
        self.headers.push(RecordHeader::pack(r));
        self.words.extend_from_slice(&r.bits.words);
        Ok(self.headers.len() - 1)
    }

    /// Appends an already packed record: `words` must be a whole map (`words_per_map(M)`
    /// words) whose hierarchy codes agree with its bits. Returns its index.
    pub fn push_packed(&mut self, header: RecordHeader, words: &[u64]) -> Result<usize> {
        let n = words_per_map(self.m);
        let consistent = words.len() == n
            && VisibilityBits::from_bit_words(self.m, &words[..bit_words(self.m)])
                .is_ok_and(|b| *b.words == *words);
        if !consistent {
            return Err(Error::invalid(
                "words",
                "must be a whole map whose hierarchy codes agree with its bits",
            ));
        }
        self.headers.push(header);
        self.words.extend_from_slice(words);
        Ok(self.headers.len() - 1)
    }

    /// The fixed fields of record `i`.
    pub fn header(&self, i: usize) -> &RecordHeader {
        &self.headers[i]
    }

    /// The fixed fields of record `i`, mutable (counters).
    pub fn header_mut(&mut self, i: usize) -> &mut RecordHeader {
        &mut self.headers[i]
    }

    /// The visibility map of record `i`.
    #[inline]
    pub fn bits(&self, i: usize) -> VisibilityView<'_> {
        let n = words_per_map(self.m);
        VisibilityView {
            m: self.m,
            words: &self.words[i * n..(i + 1) * n],
        }
    }

    /// Record `i`, unpacked (normal and `A` as quantised).
    pub fn record(&self, i: usize) -> Record {
        let h = &self.headers[i];
        Record {
            position: h.position(),
            normal: h.normal(),
            bits: VisibilityBits {
                m: self.m,
                words: self.bits(i).words.into(),
            },
            ambient_occlusion: h.ambient_occlusion(),
            nearest_hit_distance: h.nearest_hit_distance,
            misses: h.misses,
            uses: h.uses,
            last_frame: h.last_frame,
        }
    }

    /// Removes record `i`; the last record takes its index.
    pub fn swap_remove(&mut self, i: usize) {
        let n = words_per_map(self.m);
        let last = self.headers.len() - 1;
        self.headers.swap_remove(i);
        if i != last {
            self.words.copy_within(last * n..(last + 1) * n, i * n);
        }
        self.words.truncate(last * n);
    }

    /// Keeps the records for which `keep(i)` is true, in their order (ids compact).
    pub fn retain(&mut self, mut keep: impl FnMut(usize) -> bool) {
        let n = words_per_map(self.m);
        let mut next = 0;
        for i in 0..self.headers.len() {
            if keep(i) {
                if next != i {
                    self.headers[next] = self.headers[i];
                    self.words.copy_within(i * n..(i + 1) * n, next * n);
                }
                next += 1;
            }
        }
        self.headers.truncate(next);
        self.words.truncate(next * n);
    }

    /// Bytes the records occupy: `len · bytes_per_record(M)` (spare capacity excluded).
    pub fn memory_bytes(&self) -> usize {
        self.len() * bytes_per_record(self.m)
    }
}
