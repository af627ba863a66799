//! WGS84 → UTM throughput: the cached projections of `infraloc::geo` against the baseline of
//! building the proj4rs objects from their proj strings for every call (what the cache avoids).
//! Also `load_tile` + `find_tile` on a realistic tile (100 m × 100 m: satellite 1000² RGB at
//! 0.1 m, LiDAR 500² at 0.2 m).
//!
//! Run: `cargo bench --bench geo`

use criterion::{criterion_group, criterion_main, Criterion};
use infraloc::geo::{utm_epsg_for, wgs84_to_map};
use infraloc::map::cache::{find_tile, load_tile, write_tile};
use infraloc::map::{Crs, GeoGrid, Raster, Tile};
use proj4rs::proj::Proj;
use proj4rs::transform::{transform, Transform, TransformClosure};
use std::hint::black_box;

struct Pt(f64, f64);
impl Transform for Pt {
    fn transform_coordinates<F: TransformClosure>(
        &mut self,
        f: &mut F,
    ) -> proj4rs::errors::Result<()> {
        let (x, y, _) = f(self.0, self.1, 0.0)?;
        self.0 = x;
        self.1 = y;
        Ok(())
    }
}

fn bench_projection(c: &mut Criterion) {
    let (lat, lon) = (39.961_234, -82.998_765);
    let crs = Crs::Epsg(utm_epsg_for(lat, lon));
    let mut g = c.benchmark_group("wgs84_to_utm");
    g.bench_function("baseline_build_proj_per_call", |b| {
        b.iter(|| {
            let src = Proj::from_proj_string("+proj=longlat +datum=WGS84 +no_defs").unwrap();
            let dst = Proj::from_proj_string("+proj=utm +zone=17 +datum=WGS84 +units=m +no_defs")
                .unwrap();
            let mut p = Pt(black_box(lon).to_radians(), black_box(lat).to_radians());
            transform(&src, &dst, &mut p).unwrap();
            black_box((p.0, p.1))
        })
    });
    g.bench_function("infraloc_cached", |b| {
        b.iter(|| wgs84_to_map(crs, black_box(lat), black_box(lon)).unwrap())
    });
    g.finish();
}

fn bench_tile(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let crs = Crs::Epsg(32617);
    let grid = |res: f64, n: usize| GeoGrid {
        crs,
        x0: 330_000.0,
        y0: 4_425_000.0,
        res,
        width: n,
        height: n,
    };
    let (sat, lidar) = (grid(0.1, 1000), grid(0.2, 500));
    let tile = Tile {
        id: "bench".into(),
        satellite: Some(Raster {
            grid: sat,
            data: (0..sat.len())
                .map(|i| [(i % 251) as u8, (i % 13) as u8, 7])
                .collect(),
            nodata: None,
        }),
        reflectivity: Raster {
            grid: lidar,
            data: (0..lidar.len()).map(|i| (i % 255) as u8).collect(),
            nodata: Some(0),
        },
        height: Raster {
            grid: lidar,
            data: (0..lidar.len())
                .map(|i| 200.0 + (i % 97) as f32 * 0.01)
                .collect(),
            nodata: None,
        },
        control_points: vec![],
    };
    write_tile(dir.path(), &tile).unwrap();
    let (lat, lon) = infraloc::geo::map_to_wgs84(crs, 330_050.0, 4_424_950.0).unwrap();
    let mut g = c.benchmark_group("tile_cache");
    g.sample_size(10);
    g.bench_function("find_tile", |b| {
        b.iter(|| find_tile(dir.path(), black_box(lat), black_box(lon), 10.0).unwrap())
    });
    g.bench_function("load_tile_100m", |b| {
        b.iter(|| load_tile(&dir.path().join("bench")).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench_projection, bench_tile);
criterion_main!(benches);
