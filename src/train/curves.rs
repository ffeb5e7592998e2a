//! `pinc train`'s record of a run: the per-epoch CSV written as it trains, read back, and its
//! curves drawn (`pinc plot-training` redraws them from the CSV).

use super::{EpochRecord, LossKind, TrainConfig};
use crate::plot::{Panel, Series, figure};
use std::io::Write;
use std::path::Path;

/// The per-epoch CSV: a header naming every active loss, then one row per epoch. A write
/// error is kept (training goes on) and reported at the end.
pub struct EpochCsv {
    file: std::fs::File,
    /// The first write error, if any.
    pub error: Option<std::io::Error>,
}

impl EpochCsv {
    /// Creates the file at `path` and writes its header: the columns of `cfg`'s losses.
    pub fn create(path: &Path, cfg: &TrainConfig) -> Result<Self, String> {
        let mut file = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let header: Vec<String> = ["epoch", "lr"]
            .into_iter()
            .map(String::from)
            .chain(cfg.losses.iter().map(|k| format!("train_{}", k.name())))
            .chain(
                ["dev_one_step_mse", "dev_rollout10_mse", "dev_vpt_s", "dev_smoothed", "best", "elapsed_s"]
                    .map(String::from),
            )
            .collect();
        writeln!(file, "{}", header.join(",")).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(Self { file, error: None })
    }

    /// Writes one epoch's row (an error is kept in `error`).
    pub fn row(&mut self, r: &EpochRecord) {
        let mut row = vec![r.epoch.to_string(), format!("{:e}", r.lr)];
        row.extend(r.train.iter().map(|(_, v)| format!("{v:e}")));
        row.extend([
            format!("{:e}", r.dev_one_step),
            format!("{:e}", r.dev_rollout10),
            format!("{}", r.dev_vpt),
            format!("{:e}", r.dev_smoothed),
            (r.best as u8).to_string(),
            format!("{:.3}", r.elapsed_s),
        ]);
        if let Err(e) = writeln!(self.file, "{}", row.join(",")) {
            self.error.get_or_insert(e);
        }
    }
}

/// The epochs of a per-epoch CSV (the columns `EpochCsv` writes; `train_<loss>` for each
/// active loss).
pub fn read_history(path: &Path) -> Result<Vec<EpochRecord>, String> {
    let mut reader = csv::Reader::from_path(path).map_err(|e| e.to_string())?;
    let header = reader.headers().map_err(|e| e.to_string())?.clone();
    let column = |name: &str| header.iter().position(|h| h == name).ok_or(format!("no column {name:?}"));
    let losses: Vec<(usize, LossKind)> = header
        .iter()
        .enumerate()
        .filter_map(|(i, h)| h.strip_prefix("train_").map(|n| (i, n)))
        .map(|(i, n)| LossKind::from_name(n).map(|k| (i, k)).ok_or(format!("unknown loss column train_{n}")))
        .collect::<Result<_, _>>()?;
    let [epoch, lr, one, roll, vpt, smoothed, best, elapsed] =
        ["epoch", "lr", "dev_one_step_mse", "dev_rollout10_mse", "dev_vpt_s", "dev_smoothed", "best", "elapsed_s"]
            .map(column);
    let (epoch, lr, one, roll, vpt, smoothed, best, elapsed) =
        (epoch?, lr?, one?, roll?, vpt?, smoothed?, best?, elapsed?);
    let mut history = Vec::new();
    for (row, record) in reader.records().enumerate() {
        let record = record.map_err(|e| e.to_string())?;
        let line = row + 2;
        let number = |i: usize| -> Result<f64, String> {
            let text = record.get(i).unwrap_or("");
            text.parse().map_err(|_| format!("line {line}: column {}: {text:?} is not a number", &header[i]))
        };
        history.push(EpochRecord {
            epoch: number(epoch)? as usize,
            lr: number(lr)?,
            train: losses.iter().map(|&(i, k)| number(i).map(|v| (k, v))).collect::<Result<_, _>>()?,
            dev_one_step: number(one)?,
            dev_rollout10: number(roll)?,
            dev_vpt: number(vpt)?,
            dev_smoothed: number(smoothed)?,
            best: number(best)? != 0.0,
            elapsed_s: number(elapsed)?,
        });
    }
    if history.is_empty() {
        return Err("no epochs".into());
    }
    Ok(history)
}

/// The training curves (training losses, dev losses, dev VPT, learning rate) as a PNG.
pub fn plot_history(path: &Path, h: &[EpochRecord]) -> Result<(), String> {
    let Some(first) = h.first() else { return Ok(()) };
    let train_series: Vec<Series> = first
        .train
        .iter()
        .enumerate()
        .map(|(i, (k, _))| Series {
            label: k.name(),
            points: h.iter().map(|r| (r.epoch as f64, r.train[i].1)).collect(),
            color: i,
            dashed: false,
        })
        .collect();
    let ep =
        |f: &dyn Fn(&EpochRecord) -> f64| -> Vec<(f64, f64)> { h.iter().map(|r| (r.epoch as f64, f(r))).collect() };
    let panels = vec![
        Panel { title: "training losses", x_label: "epoch", y_label: "MSE", log_y: true, series: train_series },
        Panel {
            title: "dev losses",
            x_label: "epoch",
            y_label: "MSE",
            log_y: true,
            series: vec![
                Series { label: "one-step", points: ep(&|r| r.dev_one_step), color: 0, dashed: false },
                Series { label: "10-step rollout", points: ep(&|r| r.dev_rollout10), color: 1, dashed: false },
                Series { label: "rollout, smoothed", points: ep(&|r| r.dev_smoothed), color: 6, dashed: true },
            ],
        },
        Panel {
            title: "dev valid prediction time",
            x_label: "epoch",
            y_label: "s",
            log_y: false,
            series: vec![Series { label: "", points: ep(&|r| r.dev_vpt), color: 2, dashed: false }],
        },
        Panel {
            title: "learning rate",
            x_label: "epoch",
            y_label: "lr",
            log_y: true,
            series: vec![Series { label: "", points: ep(&|r| r.lr), color: 3, dashed: false }],
        },
    ];
    figure(path, 1400, 1000, 2, &panels)
}
