//! The page: one HTML file with its script and style inline, compiled into the binary. It
//! fetches nothing from anywhere but its own WebSocket (sites are often offline).
//!
//! Its contract with tests and outside tools, kept as is: each drawn sensor is an element
//! with `data-sensor="<id>"` and `data-pose="<x_m> <y_m> <yaw_deg>"`, and `<body>` gets
//! `data-ready="1"` once the first state and points are drawn.

/// `page.html`, served at `/`.
pub const HTML: &str = include_str!("page.html");

/// What the page may load and connect to: itself only (inline script and style are its own).
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_is_self_contained_and_keeps_its_contract() {
        for outside in [
            "http://",
            "https://",
            "//cdn",
            "@import",
            "fonts.googleapis",
        ] {
            // The SVG namespace is a name, never fetched.
            let hits: Vec<&str> = HTML
                .lines()
                .filter(|l| l.contains(outside) && !l.contains("http://www.w3.org/2000/svg"))
                .collect();
            assert!(hits.is_empty(), "{outside}: {hits:?}");
        }
        for attribute in ["data-sensor", "data-pose", "data-ready"] {
            assert!(HTML.contains(attribute), "{attribute}");
        }
        assert!(HTML.len() < 200_000, "page weight {} bytes", HTML.len());
    }
}
