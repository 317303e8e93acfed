//! An attended campaign on hardware: the trim masses that set each cell's
//! mass asymmetry (thesis 5.2.1), the operator's prompt and answers, and the
//! run that waits for them.

use super::*;

/// Whole trim masses on the two secondary stages that set a mass
/// asymmetry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrimMasses {
    /// Trim masses on stage 2.
    pub stage2: u32,
    /// Trim masses on stage 3.
    pub stage3: u32,
    /// The asymmetry they give, `(m2 + n2·δ)/(m3 + n3·δ) − 1`.
    pub achieved_mass_asymmetry: f64,
}

/// The whole number of trim masses of `increment_kg` on stage 2 (for
/// Δm23 ≥ m2/m3 − 1) or stage 3 (below) nearest to mass asymmetry
/// `target`, for secondary stages of `m2_kg`, `m3_kg` without trim masses
/// (thesis 5.2.1: 0.5 g masses on the 60 g stages, 0.8 % each).
/// Δm23 = m2/m3 − 1.
pub fn trim_masses(m2_kg: f64, m3_kg: f64, increment_kg: f64, target: f64) -> TrimMasses {
    let (n2, n3) = if m2_kg <= m3_kg * (1.0 + target) {
        (
            ((m3_kg * (1.0 + target) - m2_kg) / increment_kg).round(),
            0.0,
        )
    } else {
        (
            0.0,
            ((m2_kg / (1.0 + target) - m3_kg) / increment_kg).round(),
        )
    };
    TrimMasses {
        stage2: n2 as u32,
        stage3: n3 as u32,
        achieved_mass_asymmetry: (m2_kg + n2 * increment_kg) / (m3_kg + n3 * increment_kg) - 1.0,
    }
}

/// What the operator answers before a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OperatorAnswer {
    /// The setup is changed: run the cell.
    Run,
    /// Skip this cell (journaled as skipped).
    Skip,
    /// Run the previous cell again first.
    RedoPrevious,
    /// Stop the campaign (resumable).
    Stop,
}

/// The person at the bench: shown the instructions, answers.
pub trait Operator {
    /// Shows `instructions` and waits for the answer.
    ///
    /// # Errors
    /// The I/O error of asking (a closed input counts as
    /// [`OperatorAnswer::Stop`], not an error).
    fn ask(&mut self, instructions: &str) -> io::Result<OperatorAnswer>;
}

/// An operator on a text stream: instructions to `out`, one answer per
/// line from `input` (empty line: run; `s`: skip; `r`: redo the previous
/// cell; `q`: stop; end of input: stop). Anything else is asked again.
pub struct LineOperator<R, W> {
    /// Answers.
    pub input: R,
    /// Where the instructions go.
    pub out: W,
}

impl<R: io::BufRead, W: Write> Operator for LineOperator<R, W> {
    fn ask(&mut self, instructions: &str) -> io::Result<OperatorAnswer> {
        loop {
            write!(
                self.out,
                "{instructions}\n  [Enter] run · s skip · r redo the previous cell · q stop: "
            )?;
            self.out.flush()?;
            let mut line = String::new();
            if self.input.read_line(&mut line)? == 0 {
                writeln!(self.out)?;
                return Ok(OperatorAnswer::Stop);
            }
            match line.trim() {
                "" => return Ok(OperatorAnswer::Run),
                "s" | "skip" => return Ok(OperatorAnswer::Skip),
                "r" | "redo" => return Ok(OperatorAnswer::RedoPrevious),
                "q" | "quit" | "stop" => return Ok(OperatorAnswer::Stop),
                other => writeln!(self.out, "  not an answer: {other:?}")?,
            }
        }
    }
}

/// The setup of the bench: operating point and trim masses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Setup {
    pub(super) operating_point_m: f64,
    pub(super) masses: TrimMasses,
}

/// What the operator must change from `from` (unknown at the start of a
/// session) to reach `cell`.
pub(super) fn instructions(
    campaign: &Campaign,
    position: (usize, usize),
    cell: &Cell,
    from: Option<&Setup>,
    to: &Setup,
) -> String {
    let mm = |m: f64| m * 1e3;
    let mut s = format!(
        "cell {} of {} (grid cell {}): operating point Y1o = {:.3} mm ({:.2} % of L)",
        position.0,
        position.1,
        cell.index,
        mm(to.operating_point_m),
        100.0 * to.operating_point_m / campaign.config.plant.beam.length_m
    );
    if let Some(f) = from {
        let d = to.operating_point_m - f.operating_point_m;
        if d == 0.0 {
            s.push_str(", unchanged");
        } else {
            s.push_str(&format!(
                ", move {:+.3} mm from {:.3} mm",
                mm(d),
                mm(f.operating_point_m)
            ));
        }
    }
    let g = campaign.spec.mass_increment_kg * 1e3;
    let change = |now: u32, was: Option<u32>| match was {
        Some(w) if now > w => format!(" (add {})", now - w),
        Some(w) if now < w => format!(" (remove {})", w - now),
        Some(_) => " (unchanged)".to_string(),
        None => String::new(),
    };
    s.push_str(&format!(
        "\n  trim masses of {g} g: {} on stage 2{}, {} on stage 3{} -> Δm23 = {:+.2} % (grid {:+.2} %)",
        to.masses.stage2,
        change(to.masses.stage2, from.map(|f| f.masses.stage2)),
        to.masses.stage3,
        change(to.masses.stage3, from.map(|f| f.masses.stage3)),
        100.0 * to.masses.achieved_mass_asymmetry,
        100.0 * cell.mass_asymmetry
    ));
    s.push_str("\n  the amplifier is disabled at 0 A until you answer");
    s
}

/// Runs the cells of `campaign` not yet done or skipped on hardware
/// (`bench`: a backend or the daemon), one at a time in the serpentine order, each only after the
/// operator confirmed the setup they were told to make. Between cells the
/// backend is closed (the amplifier disabled at 0 A, as every chirp leaves
/// it); nothing is opened before the answer.
///
/// # Errors
/// As [`run_cells`]; [`CampaignRunError::Stopped`] when the operator
/// stops or the input ends.
pub fn run_attended(
    campaign: &Campaign,
    dir: &Path,
    journal: Journal,
    already: &ReadJournal,
    bench: &CellBench,
    operator: &mut dyn Operator,
    stop: &Arc<AtomicBool>,
) -> Result<CampaignSummary, CampaignRunError> {
    let p = &campaign.config.plant;
    let setup_of = |c: &Cell| Setup {
        operating_point_m: c.operating_point_m,
        masses: trim_masses(
            p.m2_kg,
            p.m3_kg,
            campaign.spec.mass_increment_kg,
            c.mass_asymmetry,
        ),
    };
    let skipped = already.skipped();
    let mut todo: std::collections::VecDeque<Cell> = campaign
        .serpentine()
        .into_iter()
        .filter(|c| done_entry(already, c).is_none() && !skipped.contains(&c.index))
        .collect();
    let total = todo.len();
    let journal = Mutex::new(journal);
    let mut current: Option<Setup> = None;
    let mut previous: Option<Cell> = None;
    let mut finished = 0;
    let mut stopped = false;
    while let Some(cell) = todo.front().copied() {
        if stop.load(Ordering::SeqCst) {
            stopped = true;
            break;
        }
        let to = setup_of(&cell);
        let text = instructions(
            campaign,
            ((finished + 1).min(total), total),
            &cell,
            current.as_ref(),
            &to,
        );
        let answer = operator.ask(&text).map_err(|e| CampaignRunError::Io {
            path: PathBuf::from("(operator)"),
            source: e,
        })?;
        match answer {
            OperatorAnswer::Stop => {
                stopped = true;
                break;
            }
            OperatorAnswer::Skip => {
                journal
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .append(&Entry::Skipped { cell: cell.index })?;
                todo.pop_front();
                finished += 1;
                previous = Some(cell);
            }
            OperatorAnswer::RedoPrevious => {
                if let Some(prev) = previous.take() {
                    todo.push_front(prev);
                }
            }
            OperatorAnswer::Run => {
                run_cell(
                    campaign,
                    dir,
                    &cell,
                    &journal,
                    stop,
                    bench,
                    Some(to.masses.achieved_mass_asymmetry),
                )?;
                current = Some(to);
                todo.pop_front();
                finished += 1;
                previous = Some(cell);
            }
        }
    }
    let summary = write_results(campaign, dir)?;
    if stopped || summary.pending > 0 {
        return Err(CampaignRunError::Stopped {
            dir: dir.to_path_buf(),
            done: summary.done,
            cells: summary.cells,
        });
    }
    Ok(summary)
}
