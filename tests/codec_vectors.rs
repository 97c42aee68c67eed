//! The signal codec against vectors made by cantools (tools/make-codec-vectors.py).

use leveld::can::dbc::Database;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(serde::Deserialize)]
struct Case {
    values: BTreeMap<String, f64>,
    data: String,
}

#[test]
fn decode_and_encode_match_cantools() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let db = Database::load(&root.join("tests/data/codec_vectors.dbc")).unwrap();
    let vectors: BTreeMap<String, Vec<Case>> = serde_json::from_str(
        &std::fs::read_to_string(root.join("tests/data/codec_vectors.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(vectors.len(), 3);
    let mut checked = 0;
    for (msg, cases) in &vectors {
        let info = db.message(msg).unwrap();
        if msg == "EXT_SIGNED" {
            assert!(info.extended);
        }
        for case in cases {
            let data: Vec<u8> = (0..case.data.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&case.data[i..i + 2], 16).unwrap())
                .collect();
            let mut encoded = [0u8; 8];
            for (name, &want) in &case.values {
                let c = db.signal(msg, name).unwrap();
                let got = c.decode(&data);
                assert!(
                    (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                    "{msg}.{name}: {got} vs cantools {want} in {}",
                    case.data
                );
                c.encode(&mut encoded, want);
                checked += 1;
            }
            assert_eq!(
                hex(&encoded),
                case.data,
                "{msg}: encode of {:?}",
                case.values
            );
        }
    }
    assert!(checked > 500, "{checked}");
}

fn hex(d: &[u8]) -> String {
    d.iter().map(|b| format!("{b:02X}")).collect()
}
