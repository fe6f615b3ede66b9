//! Published coefficient tables and the comparison of a film model against them.
//!
//! Lund & Thomsen (1978), "A calculation method and data for the dynamic coefficients of
//! oil-lubricated journal bearings" (ASME, Topics in Fluid Film Bearing and Rotor Bearing
//! System Design and Optimization): two-axial-groove bearing, 20 degree grooves on the
//! horizontal diameter, isoviscous, laminar, Reynolds (Swift-Stieber) film rupture, for
//! L/D = 0.5 and 1.0. The tables are embedded (`crates/physics/data/`, copied with their
//! header from the project's shared reference folder).
//!
//! The tables' frame puts x along the load (downwards) with the journal turning x -> y; the
//! comparison converts our coefficients with [`crate::dimensionless::to_load_frame`].

use nalgebra::{Matrix2, Vector2};

use crate::dimensionless;
use crate::error::PhysicsError;
use crate::film::{Film, Running};
use crate::geometry::{BearingGeometry, BearingKind};
use crate::operating_point::{self, EquilibriumOptions};

/// One row of a table: Sommerfeld number, eccentricity, attitude and Lund's dimensionless
/// coefficients in the load frame (`Bxy = Byx` in the source).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableRow {
    pub sommerfeld: f64,
    pub eccentricity: f64,
    pub attitude_deg: f64,
    pub stiffness: Matrix2<f64>,
    pub damping: Matrix2<f64>,
}

/// A table of rows at one L/D.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub name: &'static str,
    pub slenderness: f64,
    pub rows: Vec<TableRow>,
}

const LD05: &str = include_str!("../data/lund-thomsen-1978-ld0.5.csv");
const LD10: &str = include_str!("../data/lund-thomsen-1978-ld1.0.csv");

/// Parses a table in the reference CSV layout (`#` comment lines, a header
/// `S,eps,attitude_deg,Kxx,Kxy,Kyx,Kyy,Bxx,Bxy,Byy`, one row per line). Errors name the line.
pub fn parse_table(name: &'static str, slenderness: f64, text: &str) -> Result<Table, PhysicsError> {
    let mut rows = Vec::new();
    let mut header_seen = false;
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if !header_seen {
            if line != "S,eps,attitude_deg,Kxx,Kxy,Kyx,Kyy,Bxx,Bxy,Byy" {
                return Err(PhysicsError::ConfigParse { origin: format!(" {name} line {line_no}"), message: format!("unexpected header `{line}`") });
            }
            header_seen = true;
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != 10 {
            return Err(PhysicsError::ConfigParse {
                origin: format!(" {name} line {line_no}"),
                message: format!("expected 10 fields, found {}", fields.len()),
            });
        }
        let mut v = [0.0; 10];
        for (k, f) in fields.iter().enumerate() {
            v[k] = f.trim().parse::<f64>().map_err(|e| PhysicsError::ConfigParse {
                origin: format!(" {name} line {line_no} column {}", k + 1),
                message: format!("`{f}` is not a number: {e}"),
            })?;
        }
        rows.push(TableRow {
            sommerfeld: v[0],
            eccentricity: v[1],
            attitude_deg: v[2],
            stiffness: Matrix2::new(v[3], v[4], v[5], v[6]),
            damping: Matrix2::new(v[7], v[8], v[8], v[9]),
        });
    }
    if rows.is_empty() {
        return Err(PhysicsError::ConfigParse { origin: format!(" {name}"), message: "no data rows".into() });
    }
    Ok(Table { name, slenderness, rows })
}

/// Both Lund & Thomsen tables (L/D 0.5 and 1.0).
pub fn lund_thomsen_1978() -> Vec<Table> {
    // The embedded files are part of the crate and parsed by a test; a failure here is a
    // build defect, not an input error.
    vec![
        parse_table("lund-thomsen-1978-ld0.5.csv", 0.5, LD05).expect("embedded table L/D 0.5 parses"),
        parse_table("lund-thomsen-1978-ld1.0.csv", 1.0, LD10).expect("embedded table L/D 1.0 parses"),
    ]
}

/// The bearing a table of slenderness L/D describes, with a 100 mm diameter and c/R = 0.002 (the tables are
/// dimensionless; any size gives the same groups).
pub fn table_geometry(slenderness: f64) -> BearingGeometry {
    let d = 0.1;
    BearingGeometry {
        diameter_m: d,
        length_m: slenderness * d,
        clearance_m: 0.002 * 0.5 * d,
        kind: BearingKind::TwoAxialGroove { groove_arc_deg: 20.0, groove_centre_deg: 0.0 },
    }
}

/// A model's result at one row, in the table's terms, with its errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowComparison {
    pub reference: TableRow,
    pub eccentricity: f64,
    pub attitude_deg: f64,
    /// Load frame, Lund's groups.
    pub stiffness: Matrix2<f64>,
    pub damping: Matrix2<f64>,
}

impl RowComparison {
    /// Relative error of each coefficient, in the order Kxx Kxy Kyx Kyy Bxx Bxy Byx Byy.
    pub fn coefficient_errors(&self) -> [f64; 8] {
        let (v, r) = (self.values(), self.reference_values());
        std::array::from_fn(|i| (v[i] - r[i]) / r[i].abs())
    }

    /// The allowed |model - table| for a table value: `relative` of it, or half a unit of the
    /// table's last printed digit (0.005) for values below 0.2 in magnitude, whose two-decimal
    /// rounding alone is several percent (4 % on the tables' -0.13).
    pub fn tolerance(reference: f64, relative: f64) -> f64 {
        if reference.abs() < 0.2 {
            (relative * reference.abs()).max(0.005)
        } else {
            relative * reference.abs()
        }
    }

    /// Whether every coefficient is within [`RowComparison::tolerance`] of the table.
    pub fn coefficients_within(&self, relative: f64) -> bool {
        let (v, r) = (self.values(), self.reference_values());
        (0..8).all(|i| (v[i] - r[i]).abs() <= Self::tolerance(r[i], relative))
    }

    pub const COEFFICIENT_NAMES: [&'static str; 8] = ["Kxx", "Kxy", "Kyx", "Kyy", "Bxx", "Bxy", "Byx", "Byy"];
}

/// Solves `film` at every row of `table` and returns the comparison. The film must describe
/// [`table_geometry`].
pub fn compare(film: &mut dyn Film, table: &Table) -> Result<Vec<RowComparison>, PhysicsError> {
    table.rows.iter().map(|row| compare_row(film, row)).collect()
}

/// Solves `film` at one row's Sommerfeld number and expresses the result in the table's
/// terms (load frame, Lund's groups).
pub fn compare_row(film: &mut dyn Film, row: &TableRow) -> Result<RowComparison, PhysicsError> {
    let geometry = *film.geometry();
    let running = Running { omega_rad_s: 100.0, viscosity_pa_s: 0.02 };
    // S = mu N L D / W (R/c)^2  =>  W = mu N L D (R/c)^2 / S.
    let n = running.omega_rad_s / (2.0 * std::f64::consts::PI);
    let rc = geometry.radius_m() / geometry.clearance_m;
    let w = running.viscosity_pa_s * n * geometry.length_m * geometry.diameter_m * rc * rc / row.sommerfeld;
    let op = operating_point::solve(film, &running, Vector2::new(0.0, -w), &EquilibriumOptions::default())?;
    let lund = dimensionless::lund(&op.coefficients.stiffness_n_m, &op.coefficients.damping_n_s_m, &geometry, &running, w);
    Ok(RowComparison {
        reference: *row,
        eccentricity: op.eccentricity,
        attitude_deg: op.attitude_deg,
        stiffness: dimensionless::to_load_frame(&lund.stiffness),
        damping: dimensionless::to_load_frame(&lund.damping),
    })
}

impl RowComparison {
    /// Model values in the order Kxx Kxy Kyx Kyy Bxx Bxy Byx Byy.
    pub fn values(&self) -> [f64; 8] {
        let (k, b) = (&self.stiffness, &self.damping);
        [k[(0, 0)], k[(0, 1)], k[(1, 0)], k[(1, 1)], b[(0, 0)], b[(0, 1)], b[(1, 0)], b[(1, 1)]]
    }

    /// Table values in the same order.
    pub fn reference_values(&self) -> [f64; 8] {
        let (k, b) = (&self.reference.stiffness, &self.reference.damping);
        [k[(0, 0)], k[(0, 1)], k[(1, 0)], k[(1, 1)], b[(0, 0)], b[(0, 1)], b[(1, 0)], b[(1, 1)]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_tables_parse_with_five_rows_each() {
        let t = lund_thomsen_1978();
        assert_eq!(t.len(), 2);
        assert!(t.iter().all(|t| t.rows.len() == 5));
        assert_eq!(t[0].rows[0].stiffness[(0, 1)], 5.06);
        assert_eq!(t[1].rows[4].damping[(1, 0)], 1.72);
    }

    #[test]
    fn malformed_tables_name_the_line_and_column() {
        let text = "# c\nS,eps,attitude_deg,Kxx,Kxy,Kyx,Kyy,Bxx,Bxy,Byy\n1,0.2,60,1,2,3,4,5,6,7\n1,0.2,x,1,2,3,4,5,6,7\n";
        let e = parse_table("t.csv", 0.5, text).unwrap_err().to_string();
        assert!(e.contains("line 4") && e.contains("column 3"), "{e}");
        let e = parse_table("t.csv", 0.5, "S,eps,attitude_deg,Kxx,Kxy,Kyx,Kyy,Bxx,Bxy,Byy\n1,2\n").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("10 fields"), "{e}");
        let e = parse_table("t.csv", 0.5, "a,b\n").unwrap_err().to_string();
        assert!(e.contains("header"), "{e}");
    }
}
