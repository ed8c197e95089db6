//! The render graph: dependency order, culling, barriers (validation clean), timings.

mod common;

use ash::vk;
use synosis::graph::Graph;
use synosis::vk::{Buffer, MemoryKind, Profiler};

#[test]
fn graph_orders_culls_and_times_passes() {
    let ctx = common::gpu();
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER
        | vk::BufferUsageFlags::TRANSFER_SRC
        | vk::BufferUsageFlags::TRANSFER_DST;
    let out = Buffer::new(&ctx, "out", 1024, usage, MemoryKind::Readback).unwrap();
    let out2 = Buffer::new(&ctx, "out2", 1024, usage, MemoryKind::Readback).unwrap();
    let profiler = Profiler::new();
    let mut g = Graph::new(&ctx, "test graph");
    let mut a = g.create_buffer("a", 1024).unwrap();
    let mut b = g.create_buffer("b", 1024).unwrap();
    let mut unused = g.create_buffer("unused", 1024).unwrap();
    let mut o = g.import(&out);
    let mut o2 = g.import(&out2);
    g.fill("fill a", &mut a, 7);
    g.fill("dead pass", &mut unused, 1); // nobody reads it: culled
    g.copy("a to b", &a, &mut b);
    g.fill("overwrite a", &mut a, 9); // write-after-read: must run after "a to b"
    g.copy("b to out", &b, &mut o);
    g.copy("a to out2", &a, &mut o2);
    let timings = g.execute(Some(&profiler)).unwrap();
    let names: Vec<&str> = timings.iter().map(|t| t.name.as_str()).collect();
    assert_eq!(
        names,
        ["fill a", "a to b", "overwrite a", "b to out", "a to out2"]
    );
    assert!(
        timings
            .iter()
            .all(|t| t.gpu_ms >= 0.0 && t.gpu_ms.is_finite())
    );
    assert!(
        out.read::<u32>().unwrap().iter().all(|&v| v == 7),
        "the copy saw the later overwrite"
    );
    assert!(out2.read::<u32>().unwrap().iter().all(|&v| v == 9));
    let gpu_spans = profiler.spans().iter().filter(|s| s.track == "gpu").count();
    assert_eq!(gpu_spans, 5);
    common::assert_clean(&ctx);
}

#[test]
fn dispatch_misuse_is_a_typed_error_naming_the_pass() {
    use synosis::trace::{Backend, TraceScene, trace_pipeline};
    use synosis::vk::{BindingKind, VkError};
    let ctx = common::gpu();
    // Software backend: its own bindings first, then rays, hits, hints, bundles, bundle
    // use; 16-byte push block.
    use synosis::gpu_interface::HitsBinding;
    let off = TraceScene::binding_kinds(Backend::Software).len() as u32;
    let pipe = trace_pipeline(
        &ctx,
        "hits",
        "",
        Backend::Software,
        &[synosis::vk::BindingKind::StorageBuffer; HitsBinding::COUNT],
        16,
        [64, 1, 1],
        &[],
    )
    .unwrap();
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let out = Buffer::new(&ctx, "out", 256, usage, MemoryKind::Readback).unwrap();
    let used = Buffer::new(&ctx, "used", 256, usage, MemoryKind::Readback).unwrap();
    let run = |name: &str, bind_rays: bool, push: &[u32; 4], words: usize, groups: [u32; 3]| {
        let mut g = Graph::new(&ctx, "misuse");
        let a = g.create_buffer("a", 256).unwrap();
        let mut o = g.import(&out);
        let mut u = g.import(&used);
        let mut d = g.dispatch(name, &pipe, groups);
        for b in 0..off {
            d = d.read(b, &a);
        }
        if bind_rays {
            d = d.read(off, &a);
        }
        match words {
            4 => d.push(push),
            _ => d.push(&[push[0], push[1], push[2]]),
        }
        .write(HitsBinding::Hits.at(off), &mut o)
        .read(HitsBinding::Hints.at(off), &a)
        .read(HitsBinding::Bundles.at(off), &a)
        .write(HitsBinding::BundleUse.at(off), &mut u)
        .read(HitsBinding::Shadows.at(off), &a)
        .submit();
        g.execute(None)
    };
    match run("half bound", false, &[0; 4], 4, [1, 1, 1]) {
        Err(VkError::UnboundBinding {
            pass,
            binding,
            kind: BindingKind::StorageBuffer,
            ..
        }) => assert_eq!((pass.as_str(), binding), ("half bound", off)),
        other => panic!("{other:?}"),
    }
    match run("short push", true, &[0; 4], 3, [1, 1, 1]) {
        Err(VkError::PushConstantSize {
            pass,
            expected: 16,
            given: 12,
            ..
        }) => assert_eq!(pass, "short push"),
        other => panic!("{other:?}"),
    }
    let max = ctx.info.max_workgroup_count;
    if max[0] < u32::MAX {
        match run("too wide", true, &[0; 4], 4, [max[0] + 1, 1, 1]) {
            Err(VkError::WorkgroupLimit { pass, .. }) => assert_eq!(pass, "too wide"),
            other => panic!("{other:?}"),
        }
    }
    common::assert_clean(&ctx);
}

#[test]
fn every_shader_variant_is_spirv_and_trace_shaders_have_both_backends() {
    for (name, bytes) in synosis::shaders::SHADERS {
        assert!(bytes.len() > 20 && bytes.len() % 4 == 0, "{name}");
        assert_eq!(
            u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
            0x0723_0203,
            "{name}: SPIR-V magic"
        );
    }
    for shader in ["hits", "raycast"] {
        for suffix in ["rq", "sw"] {
            assert!(
                synosis::shaders::spirv(&format!("{shader}.{suffix}")).is_some(),
                "{shader}.{suffix}"
            );
        }
    }
}

#[test]
fn validation_layer_catches_a_planted_error() {
    // Proves the layer is live: a buffer with zero size is invalid usage.
    let ctx = common::gpu();
    let info = vk::BufferCreateInfo::default()
        .size(0)
        .usage(vk::BufferUsageFlags::STORAGE_BUFFER);
    let b = unsafe { ctx.device.create_buffer(&info, None) };
    if let Ok(b) = b {
        unsafe { ctx.device.destroy_buffer(b, None) };
    }
    assert!(
        !ctx.validation_errors().is_empty(),
        "the validation layer reported nothing"
    );
}

#[test]
fn image_round_trip_through_transfers_is_exact_and_clean() {
    use synosis::vk::Image;
    let ctx = common::gpu();
    let (w, h) = (37u32, 23u32);
    let data: Vec<f32> = (0..w * h).map(|i| i as f32 * 0.25 - 7.0).collect();
    let usage = vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST;
    let src = Buffer::from_slice(&ctx, "image src", &data, usage).unwrap();
    let dst = Buffer::new(
        &ctx,
        "image dst",
        (w * h * 4) as u64,
        usage,
        MemoryKind::Readback,
    )
    .unwrap();
    let img = Image::new_2d(
        &ctx,
        "round trip",
        w,
        h,
        vk::Format::R32_SFLOAT,
        vk::ImageUsageFlags::TRANSFER_SRC
            | vk::ImageUsageFlags::TRANSFER_DST
            | vk::ImageUsageFlags::STORAGE,
    )
    .unwrap();
    let t = vk::PipelineStageFlags::TRANSFER;
    ctx.submit_and_wait(|cb| {
        img.transition(
            cb,
            (
                vk::ImageLayout::UNDEFINED,
                vk::PipelineStageFlags::TOP_OF_PIPE,
                vk::AccessFlags::empty(),
            ),
            (
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                t,
                vk::AccessFlags::TRANSFER_WRITE,
            ),
        );
        img.copy_from_buffer(cb, &src);
        img.transition(
            cb,
            (
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                t,
                vk::AccessFlags::TRANSFER_WRITE,
            ),
            (
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                t,
                vk::AccessFlags::TRANSFER_READ,
            ),
        );
        img.copy_to_buffer(cb, &dst);
        let host = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::HOST_READ);
        unsafe {
            ctx.device.cmd_pipeline_barrier(
                cb,
                t,
                vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &[host],
                &[],
                &[],
            )
        };
        Ok(())
    })
    .unwrap();
    assert_eq!(dst.read::<f32>().unwrap(), data);
    drop(img);
    common::assert_clean(&ctx);
}
