//! COCO labels: each image's fragment (`images/<id>/coco.json`, its annotations without
//! ids) and the split files (`coco/<split>.json`) the finish step joins them into.
//!
//! A split file is written as a stream: the fragments are read one at a time while the
//! document is serialised, so the finish step holds one image's annotations, not the
//! whole split's (10 KiB or so an image: a million images would have held gigabytes). The
//! bytes are those of the document built whole and pretty-printed by serde_json (key order
//! included: `annotations`, `categories`, `images`, `info`); the file goes to a temporary
//! name and is renamed into place, so a failure leaves the previous file or none.

use std::cell::RefCell;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::ser::{Error as _, SerializeMap, SerializeSeq};
use serde::{Serialize, Serializer};
use serde_json::json;

use super::error::{DatasetError, Result};
use super::labels;
use super::post::{self, Frame};

/// The image's COCO annotations (ids assigned when the split files are built).
pub(super) fn fragment(f: &Frame) -> serde_json::Value {
    let anns: Vec<serde_json::Value> = post::defect_pixels(&f.class, &f.instance)
        .into_iter()
        .map(|(id, class, area)| {
            let mask: Vec<bool> = f.instance.iter().map(|&i| i == id).collect();
            let counts = labels::rle_counts(&mask, f.width, f.height);
            let [x, y, w, h] = labels::bbox(&mask, f.width).unwrap_or([0; 4]);
            json!({
                "instance": id,
                "category_id": class,
                "segmentation": {"size": [f.height, f.width], "counts": labels::rle_encode_string(&counts)},
                "area": area,
                "bbox": [x, y, w, h],
                "iscrowd": 0,
            })
        })
        .collect();
    json!({ "annotations": anns })
}

/// One image of a split file: what its `images` entry says and where its fragment is.
#[derive(Clone, Copy, Debug)]
pub(super) struct SplitImage<'a> {
    /// The image's index in the job: its COCO `id` and its annotations' `image_id`.
    pub index: usize,
    /// The image's folder under `images/`, which holds its fragment.
    pub id: &'a str,
    /// `file_name`: the image's path relative to the dataset folder.
    pub file_name: &'a str,
    pub width: u32,
    pub height: u32,
}

/// Writes `path` (a split file) from the fragments of `images` under `dir/images/`, in
/// their order; annotation ids count from 1 in that order. Errors naming a fragment that
/// cannot be read or parsed; the file is then left as it was.
pub(super) fn write_split(
    dir: &Path,
    split: &str,
    images: &[SplitImage<'_>],
    path: &Path,
) -> Result<()> {
    let doc = SplitDoc {
        dir,
        split,
        images,
        failed: RefCell::new(None),
    };
    let written = crate::util::write_atomic_with(path, |f| {
        let mut w = std::io::BufWriter::with_capacity(1 << 16, f);
        serde_json::to_writer_pretty(&mut w, &doc).map_err(std::io::Error::other)?;
        w.flush()
    });
    // A fragment's error, which the serialiser only saw as a message, comes first.
    if let Some(e) = doc.failed.into_inner() {
        return Err(e);
    }
    written.map_err(|e| DatasetError::io(path, e))
}

struct SplitDoc<'a> {
    dir: &'a Path,
    split: &'a str,
    images: &'a [SplitImage<'a>],
    /// The first fragment that could not be read, with its path.
    failed: RefCell<Option<DatasetError>>,
}

impl SplitDoc<'_> {
    fn fragment_path(&self, image: &SplitImage<'_>) -> PathBuf {
        self.dir.join("images").join(image.id).join("coco.json")
    }

    fn read_fragment(&self, image: &SplitImage<'_>) -> Result<serde_json::Value> {
        let path = self.fragment_path(image);
        let text = std::fs::read_to_string(&path).map_err(|e| DatasetError::io(&path, e))?;
        serde_json::from_str(&text).map_err(|e| DatasetError::io(&path, std::io::Error::other(e)))
    }
}

impl Serialize for SplitDoc<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        // The keys in serde_json's map order (sorted), as the whole document had them.
        let mut m = s.serialize_map(Some(4))?;
        m.serialize_entry("annotations", &Annotations(self))?;
        m.serialize_entry(
            "categories",
            &json!([
                {"id": 1, "name": "dent", "supercategory": "defect"},
                {"id": 2, "name": "scratch", "supercategory": "defect"},
            ]),
        )?;
        m.serialize_entry("images", &Images(self.images))?;
        m.serialize_entry(
            "info",
            &json!({
                "description": format!("synosis synthetic dataset, {} split", self.split),
                "version": "1",
            }),
        )?;
        m.end()
    }
}

/// Every fragment's annotations in image order, each given its `id` and `image_id`.
struct Annotations<'a>(&'a SplitDoc<'a>);

impl Serialize for Annotations<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let doc = self.0;
        let mut seq = s.serialize_seq(None)?;
        let mut next_id = 1usize;
        for image in doc.images {
            let frag = match doc.read_fragment(image) {
                Ok(v) => v,
                Err(e) => {
                    let msg = e.to_string();
                    doc.failed.borrow_mut().get_or_insert(e);
                    return Err(S::Error::custom(msg));
                }
            };
            let Some(list) = frag.get("annotations").and_then(|a| a.as_array()) else {
                continue;
            };
            for a in list {
                let mut a = a.clone();
                if let Some(o) = a.as_object_mut() {
                    o.insert("id".into(), json!(next_id));
                    o.insert("image_id".into(), json!(image.index));
                }
                seq.serialize_element(&a)?;
                next_id += 1;
            }
        }
        seq.end()
    }
}

struct Images<'a>(&'a [SplitImage<'a>]);

impl Serialize for Images<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.len()))?;
        for e in self.0 {
            seq.serialize_element(&json!({
                "id": e.index, "file_name": e.file_name, "width": e.width, "height": e.height,
            }))?;
        }
        seq.end()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The split document built whole, as the finish step did before it streamed: the
    /// reference the streamed bytes must equal.
    fn whole(dir: &Path, split: &str, images: &[SplitImage<'_>]) -> Vec<u8> {
        let mut list = Vec::new();
        let mut anns = Vec::new();
        for e in images {
            list.push(json!({"id": e.index, "file_name": e.file_name, "width": e.width, "height": e.height}));
            let path = dir.join("images").join(e.id).join("coco.json");
            let frag: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            if let Some(l) = frag.get("annotations").and_then(|a| a.as_array()) {
                for a in l {
                    let mut a = a.clone();
                    let o = a.as_object_mut().unwrap();
                    o.insert("id".into(), json!(anns.len() + 1));
                    o.insert("image_id".into(), json!(e.index));
                    anns.push(a);
                }
            }
        }
        serde_json::to_vec_pretty(&json!({
            "info": {"description": format!("synosis synthetic dataset, {split} split"), "version": "1"},
            "images": list,
            "annotations": anns,
            "categories": [
                {"id": 1, "name": "dent", "supercategory": "defect"},
                {"id": 2, "name": "scratch", "supercategory": "defect"},
            ],
        }))
        .unwrap()
    }

    fn frame(w: usize, h: usize, defects: &[(u16, u8, [usize; 4])]) -> Frame {
        let mut class = vec![0u8; w * h];
        let mut instance = vec![0u16; w * h];
        for &(id, c, [x0, y0, x1, y1]) in defects {
            for y in y0..y1 {
                for x in x0..x1 {
                    class[y * w + x] = c;
                    instance[y * w + x] = id;
                }
            }
        }
        Frame {
            width: w,
            height: h,
            class,
            instance,
            image: vec![0.0; w * h],
            object: vec![0; w * h],
        }
    }

    fn put_fragment(dir: &Path, id: &str, f: &Frame) {
        let d = dir.join("images").join(id);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(
            d.join("coco.json"),
            serde_json::to_vec_pretty(&fragment(f)).unwrap(),
        )
        .unwrap();
    }

    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("synosis-coco-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn streamed_split_equals_the_whole_document_byte_for_byte() {
        let dir = temp_dir("same");
        put_fragment(
            &dir,
            "000003",
            &frame(9, 7, &[(2, 1, [1, 1, 4, 3]), (5, 2, [6, 0, 7, 7])]),
        );
        put_fragment(&dir, "000004", &frame(9, 7, &[]));
        put_fragment(&dir, "000009", &frame(8, 6, &[(1, 2, [0, 5, 8, 6])]));
        let images = [
            SplitImage {
                index: 3,
                id: "000003",
                file_name: "images/000003/image.png",
                width: 9,
                height: 7,
            },
            SplitImage {
                index: 4,
                id: "000004",
                file_name: "images/000004/image.png",
                width: 9,
                height: 7,
            },
            SplitImage {
                index: 9,
                id: "000009",
                file_name: "images/000009/image.png",
                width: 8,
                height: 6,
            },
        ];
        let path = dir.join("train.json");
        write_split(&dir, "train", &images, &path).unwrap();
        let got = std::fs::read(&path).unwrap();
        assert_eq!(
            String::from_utf8(got).unwrap(),
            String::from_utf8(whole(&dir, "train", &images)).unwrap()
        );
        let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        let ids: Vec<u64> = v["annotations"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a["id"].as_u64().unwrap())
            .collect();
        assert_eq!(ids, [1, 2, 3]);
        // Empty splits (no images; images without annotations) too.
        write_split(&dir, "val", &[], &path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), whole(&dir, "val", &[]));
        write_split(&dir, "test", &images[1..2], &path).unwrap();
        assert_eq!(
            std::fs::read(&path).unwrap(),
            whole(&dir, "test", &images[1..2])
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_unreadable_fragment_is_named_and_leaves_the_split_file_as_it_was() {
        let dir = temp_dir("bad");
        put_fragment(&dir, "000000", &frame(4, 4, &[(1, 1, [0, 0, 2, 2])]));
        std::fs::create_dir_all(dir.join("images/000001")).unwrap();
        std::fs::write(dir.join("images/000001/coco.json"), b"{\"annotations\": [").unwrap();
        let images = [
            SplitImage {
                index: 0,
                id: "000000",
                file_name: "a.png",
                width: 4,
                height: 4,
            },
            SplitImage {
                index: 1,
                id: "000001",
                file_name: "b.png",
                width: 4,
                height: 4,
            },
            SplitImage {
                index: 2,
                id: "000002",
                file_name: "c.png",
                width: 4,
                height: 4,
            },
        ];
        let path = dir.join("train.json");
        std::fs::write(&path, b"before").unwrap();
        let err = write_split(&dir, "train", &images, &path)
            .unwrap_err()
            .to_string();
        assert!(err.contains("000001") && err.contains("coco.json"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), b"before");
        // A missing fragment likewise; no temporary file is left beside the split file.
        std::fs::write(dir.join("images/000001/coco.json"), b"{}").unwrap();
        let err = write_split(&dir, "train", &images, &path)
            .unwrap_err()
            .to_string();
        assert!(err.contains("000002"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), b"before");
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
