//! `firmware keygen` and `firmware sign`: the owner's key and signed images
//! (docs/flashing.md, "Signed images"). The key files are PEM, as openssl writes
//! ed25519 keys: the secret key PKCS#8, the public key SPKI beside it as `KEY.pub`.

use std::io::Write;
use std::path::{Path, PathBuf};

use base_core::update::signature::{self, DOWNGRADE, PublicKey};
use ed25519_compact::{KeyPair, Seed};

use crate::base::Error;
use crate::firmware::check_file;

/// The key's short name in messages: its first 8 bytes in hex.
pub fn key_id(key: &PublicKey) -> String {
    key[..8].iter().map(|byte| format!("{byte:02x}")).collect()
}

/// Where the public key of the secret key at `secret` goes.
pub fn public_key_path(secret: &Path) -> PathBuf {
    let mut name = secret.as_os_str().to_owned();
    name.push(".pub");
    PathBuf::from(name)
}

fn read_secret_key(path: &Path) -> Result<[u8; 32], Error> {
    let text = read_text(path)?;
    KeyPair::from_pem(&text)
        .map(|pair| *pair.sk.seed())
        .map_err(|error| {
            Error::InvalidInput(format!(
                "{}: not an ed25519 secret key in PKCS#8 PEM ({error}); \
                 `basectl firmware keygen` or `openssl genpkey -algorithm ed25519` makes one",
                path.display()
            ))
        })
}

fn read_text(path: &Path) -> Result<String, Error> {
    std::fs::read_to_string(path)
        .map_err(|error| Error::InvalidInput(format!("cannot read {}: {error}", path.display())))
}

/// Writes `text` to a new file: an existing key is never overwritten.
fn create(path: &Path, text: &str, secret: bool) -> Result<(), Error> {
    use std::os::unix::fs::OpenOptionsExt;
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(if secret { 0o600 } else { 0o644 })
        .open(path)
        .map_err(|error| {
            Error::InvalidInput(format!("cannot create {}: {error}", path.display()))
        })?;
    file.write_all(text.as_bytes())?;
    Ok(())
}

/// `firmware keygen KEY`: a new secret key in KEY (readable by its owner only) and its
/// public key in KEY.pub.
pub fn keygen(secret_path: &Path, out: &mut dyn Write) -> Result<(), Error> {
    let public_path = public_key_path(secret_path);
    let mut seed = [0u8; 32];
    getrandom::fill(&mut seed)
        .map_err(|error| Error::InvalidInput(format!("no randomness for a key: {error}")))?;
    let pair = KeyPair::from_seed(Seed::new(seed));
    if public_path.exists() {
        return Err(Error::InvalidInput(format!(
            "{} exists: a key is never overwritten",
            public_path.display()
        )));
    }
    create(secret_path, &pair.sk.to_pem(), true)?;
    create(&public_path, &pair.pk.to_pem(), false)?;
    let public = *pair.pk;
    writeln!(
        out,
        "secret key {} (keep it safe: whoever has it can update the robot)\n\
         public key {} (key {}): build the firmware with BASE_UPDATE_KEY={}",
        secret_path.display(),
        public_path.display(),
        key_id(&public),
        public_path.display()
    )?;
    Ok(())
}

/// `firmware sign --key KEY IN OUT`: IN signed with KEY, written to OUT.
pub fn sign(
    secret_path: &Path,
    input: &Path,
    output: &Path,
    allow_security_downgrade: bool,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let secret = read_secret_key(secret_path)?;
    let file = check_file(input)?;
    let flags = if allow_security_downgrade {
        DOWNGRADE
    } else {
        0
    };
    let (len, block) = signature::sign(&file.bytes, &secret, flags)
        .map_err(|error| Error::InvalidInput(format!("{}: {error:?}", input.display())))?;
    let mut signed = file.bytes[..len].to_vec();
    signed.extend_from_slice(&block.to_bytes());
    std::fs::write(output, &signed).map_err(|error| {
        Error::InvalidInput(format!("cannot write {}: {error}", output.display()))
    })?;
    writeln!(
        out,
        "{}: firmware {} (security version {}) signed with key {}{}",
        output.display(),
        file.version,
        file.security_version,
        key_id(&block.key),
        if allow_security_downgrade {
            ", allowed below the running security version"
        } else {
            ""
        }
    )?;
    Ok(())
}
