//! Who may take part in a run across hosts: an authority of the user's,
//! a key and certificate per host (and one for the launcher), all made by
//! `cqnet hosts keys`, and the Zenoh configuration that makes the hosts'
//! sessions QUIC, mutually authenticated by its TLS 1.3, with access
//! control by name.
//!
//! Three layers keep a stranger out of a run:
//!
//! 1. **TLS with mutual authentication**, in QUIC (`quic/` endpoints). A
//!    peer without a certificate from the authority gets no session at
//!    all: the handshake fails before any Zenoh message passes, and
//!    everything after it is encrypted. Zenoh's `tls/` link would do the
//!    same over TCP, but it reads and writes one TLS connection from two
//!    tasks at once, which rustls does not support, and under load it
//!    loses messages; QUIC keeps the two directions apart.
//! 2. **Access control by certificate name** (Zenoh's ACL, default deny).
//!    An agent takes commands only from the launcher's certificate and
//!    bridge traffic only from its scenario's hosts, each on its own keys,
//!    and sends nothing to anyone else. So a certificate from the same
//!    authority but of a host that is not in the scenario (another run's)
//!    is shut out too.
//! 3. **The agent's own checks** (`agent.rs`): a command for another run,
//!    or for an actor the agent does not run, is refused and counted.
//!
//! Host names are not checked against the endpoint's address
//! (`verify_name_on_connect` off): the endpoints are addresses that the
//! authority does not know when it signs, and a peer that answers on a
//! host's address with another host's certificate gets only that other
//! host's rights (layer 2).

use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

/// The launcher's name in certificates. Longer than a host name may be,
/// so no host can take it.
pub const LAUNCHER: &str = "cqnet-launcher";
/// The authority's certificate and key in a keys folder.
const AUTHORITY: &str = "authority";
/// The authority's name in its certificate.
const AUTHORITY_NAME: &str = "cqnet hosts authority";

/// A keys folder: `authority.pem`, and `<name>.pem` with `<name>.key` for
/// each host and for the launcher.
#[derive(Debug, Clone)]
pub struct Keys {
    dir: PathBuf,
}

impl Keys {
    /// The keys in `dir`, checked: the authority's certificate is there.
    pub fn open(dir: &Path) -> anyhow::Result<Self> {
        let keys = Self { dir: dir.into() };
        let authority = keys.certificate(AUTHORITY);
        if !authority.is_file() {
            bail!(
                "{} has no authority certificate ({}): make the keys with `cqnet hosts keys {} <host>…`",
                dir.display(),
                authority.display(),
                dir.display()
            );
        }
        Ok(keys)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn authority(&self) -> PathBuf {
        self.certificate(AUTHORITY)
    }

    pub fn certificate(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.pem"))
    }

    pub fn private_key(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.key"))
    }

    /// The certificate and key of `name`, checked: both there, and the key
    /// readable by its owner only (as ssh asks of its keys).
    pub fn identity(&self, name: &str) -> anyhow::Result<(PathBuf, PathBuf)> {
        let (cert, key) = (self.certificate(name), self.private_key(name));
        for f in [&cert, &key] {
            if !f.is_file() {
                bail!(
                    "no {} in {}: add it with `cqnet hosts keys {} {name}`",
                    f.file_name().unwrap_or_default().to_string_lossy(),
                    self.dir.display(),
                    self.dir.display()
                );
            }
        }
        let mode = std::fs::metadata(&key)?.permissions().mode();
        if mode & 0o077 != 0 {
            bail!(
                "{} can be read by others (mode {:o}): `chmod 600` it",
                key.display(),
                mode & 0o777
            );
        }
        Ok((cert, key))
    }
}

/// Makes (or adds to) a keys folder: the authority if it has none, then a
/// key and certificate for each of `names` and for the launcher, signed by
/// it. Names already there are kept. Every file is its owner's only; the
/// folder too. Returns the files written.
pub fn make_keys(dir: &Path, names: &[String]) -> anyhow::Result<Vec<PathBuf>> {
    for n in names {
        let ok = !n.is_empty()
            && n.len() <= 64
            && n.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
        if !ok || n == AUTHORITY {
            bail!("{n:?} is not a name for a host's keys (letters, digits, `-`, `_`; not `authority`)");
        }
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))?;
    let keys = Keys { dir: dir.into() };
    let mut written = Vec::new();
    let authority_key = if keys.private_key(AUTHORITY).is_file() {
        let pem = std::fs::read_to_string(keys.private_key(AUTHORITY))?;
        rcgen::KeyPair::from_pem(&pem).context("reading the authority's key")?
    } else {
        let key = rcgen::KeyPair::generate()?;
        let cert = authority_params().self_signed(&key)?;
        written.push(write_owner_only(
            &keys.private_key(AUTHORITY),
            &key.serialize_pem(),
        )?);
        written.push(write_owner_only(&keys.authority(), &cert.pem())?);
        key
    };
    // The issuer of a certificate is its name, key identifier and key: the
    // same parameters and key make the same issuer as the file's.
    let authority = authority_params().self_signed(&authority_key)?;
    let mut all: Vec<&str> = names.iter().map(String::as_str).collect();
    all.push(LAUNCHER);
    for name in all {
        if keys.certificate(name).is_file() && keys.private_key(name).is_file() {
            continue;
        }
        let key = rcgen::KeyPair::generate()?;
        let cert = member_params(name)?.signed_by(&key, &authority, &authority_key)?;
        written.push(write_owner_only(
            &keys.private_key(name),
            &key.serialize_pem(),
        )?);
        written.push(write_owner_only(&keys.certificate(name), &cert.pem())?);
    }
    Ok(written)
}

/// A scenario of hosts on `quic/` endpoints without keys gets the run's
/// own (authority and all), made in `dir`; others are left as they are.
/// For a launcher or harness that starts every agent itself.
pub fn add_run_keys(scenario: &mut fusion_graph::Scenario, dir: &Path) -> anyhow::Result<()> {
    let trust = scenario.trust.get_or_insert_with(Default::default);
    if scenario.hosts.is_empty() || trust.plain_tcp || trust.keys.is_some() {
        return Ok(());
    }
    let dir = std::path::absolute(dir)?;
    let names: Vec<String> = scenario.hosts.iter().map(|h| h.name.clone()).collect();
    make_keys(&dir, &names).context("making the run's keys")?;
    trust.keys = Some(dir.display().to_string());
    Ok(())
}

fn authority_params() -> rcgen::CertificateParams {
    let mut p = rcgen::CertificateParams::default();
    p.distinguished_name
        .push(rcgen::DnType::CommonName, AUTHORITY_NAME);
    p.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    p.key_usages = vec![
        rcgen::KeyUsagePurpose::KeyCertSign,
        rcgen::KeyUsagePurpose::CrlSign,
        rcgen::KeyUsagePurpose::DigitalSignature,
    ];
    p.not_before = rcgen::date_time_ymd(2024, 1, 1);
    p.not_after = rcgen::date_time_ymd(2099, 1, 1);
    p
}

/// A host's (or the launcher's) certificate: its name as the common name,
/// which Zenoh's access control matches, and as a DNS name; good for both
/// ends of a QUIC link, since a peer both listens and connects.
fn member_params(name: &str) -> anyhow::Result<rcgen::CertificateParams> {
    let mut p = rcgen::CertificateParams::new(vec![name.to_string()])?;
    p.distinguished_name.push(rcgen::DnType::CommonName, name);
    p.key_usages = vec![rcgen::KeyUsagePurpose::DigitalSignature];
    p.extended_key_usages = vec![
        rcgen::ExtendedKeyUsagePurpose::ServerAuth,
        rcgen::ExtendedKeyUsagePurpose::ClientAuth,
    ];
    p.not_before = rcgen::date_time_ymd(2024, 1, 1);
    p.not_after = rcgen::date_time_ymd(2099, 1, 1);
    Ok(p)
}

/// Writes `text` to a new file that only its owner can read or write.
fn write_owner_only(path: &Path, text: &str) -> anyhow::Result<PathBuf> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)
        .with_context(|| format!("creating {}", path.display()))?;
    f.write_all(text.as_bytes())?;
    Ok(path.into())
}

/// Every kind of message Zenoh's access control can filter.
const ALL_MESSAGES: [&str; 9] = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
];

/// Who a session belongs to, for its access control.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role<'a> {
    Launcher,
    Agent(&'a str),
}

/// Zenoh's access control for `role` in a run over `hosts` (their names):
/// default deny; the launcher and each agent exchange on the agent's
/// control keys only; agents exchange bridge traffic on each other's
/// bridge keys only.
pub fn access_control(role: Role<'_>, hosts: &[String]) -> serde_json::Value {
    use serde_json::json;
    let mut subjects = Vec::new();
    let mut rules = Vec::new();
    let mut policies = Vec::new();
    let mut grant = |subject: &str, key_exprs: Vec<String>, messages: &[&str]| {
        let n = rules.len();
        subjects.push(json!({ "id": format!("s{n}"), "cert_common_names": [subject] }));
        rules.push(json!({
            "id": format!("r{n}"),
            "messages": messages,
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": key_exprs,
        }));
        policies.push(json!({ "rules": [format!("r{n}")], "subjects": [format!("s{n}")] }));
    };
    match role {
        Role::Launcher => {
            for h in hosts {
                grant(h, vec![format!("cqnet/agent/{h}/**")], &ALL_MESSAGES);
            }
        }
        Role::Agent(me) => {
            grant(
                LAUNCHER,
                vec![format!("cqnet/agent/{me}/**")],
                &ALL_MESSAGES,
            );
            for h in hosts.iter().filter(|h| *h != me) {
                grant(
                    h,
                    vec![
                        format!("cqnet/run/*/bridge/{h}"),
                        format!("cqnet/run/*/bridge/{me}"),
                    ],
                    &["put", "declare_subscriber"],
                );
            }
        }
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("cqnet-keys-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn keys_are_owner_only_and_added_to_under_the_same_authority() {
        let dir = temp("add");
        let first = make_keys(&dir, &["a".into(), "b".into()]).unwrap();
        // authority (2), a (2), b (2), launcher (2)
        assert_eq!(first.len(), 8);
        for f in &first {
            let mode = std::fs::metadata(f).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o600, "{}", f.display());
        }
        let authority = std::fs::read(dir.join("authority.pem")).unwrap();
        let again = make_keys(&dir, &["a".into(), "c".into()]).unwrap();
        assert_eq!(again, vec![dir.join("c.key"), dir.join("c.pem")]);
        assert_eq!(std::fs::read(dir.join("authority.pem")).unwrap(), authority);
        let keys = Keys::open(&dir).unwrap();
        keys.identity("c").unwrap();
        keys.identity(LAUNCHER).unwrap();
        assert!(keys
            .identity("d")
            .unwrap_err()
            .to_string()
            .contains("no d.pem"));
        std::fs::set_permissions(dir.join("a.key"), std::fs::Permissions::from_mode(0o644))
            .unwrap();
        let err = keys.identity("a").unwrap_err().to_string();
        assert!(err.contains("can be read by others"), "{err}");
        assert!(make_keys(&dir, &["authority".into()]).is_err());
        assert!(make_keys(&dir, &["a/b".into()]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_folder_without_an_authority_is_refused() {
        let dir = temp("none");
        std::fs::create_dir_all(&dir).unwrap();
        let err = Keys::open(&dir).unwrap_err().to_string();
        assert!(err.contains("cqnet hosts keys"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
