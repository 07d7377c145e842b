//! Signed images: which images a controller lets an update activate.
//!
//! The owner of a robot signs each image with an ed25519 key (`basectl firmware sign`);
//! the controller's build carries the public keys it trusts (`BASE_UPDATE_KEY`, see
//! docs/flashing.md), so a key is set only by flashing over USB, or by an update the
//! owner signed: no CAN frame sets one. A build without a key is a development build:
//! it activates any image the bootloader would start, and says so.
//!
//! A signed image is the image tool's file, cut after its appended SHA-256, and then
//! one [`SignatureBlock`]. The bootloader reads the image's length from its segments
//! and ignores what follows the digest, so a signed image boots on any bootloader.
//! The signature covers the appended SHA-256, which the controller checks against every
//! byte before it ([`super::image::WholeImageCheck`]), so it covers the whole image,
//! and the block's flags.
//!
//! The security version (the app descriptor's `secure_version`) is the anti-rollback
//! floor: an image below the running image's security version activates only with the
//! owner's explicit consent, [`DOWNGRADE`] in its signed flags. Raising it in a
//! release retires every older image for updates over CAN.

use ed25519_compact::{KeyPair, Seed, Signature};

use super::image::{self, ImageError, SHA256_LEN, WholeImageCheck};

/// An ed25519 public key, as the key files and the block carry it.
pub type PublicKey = [u8; 32];

/// The signature block's first bytes: "base controller signature", format 1.
pub const BLOCK_MAGIC: [u8; 8] = *b"BCSIG\x00\x01\x00";
/// Magic, the signer's public key, flags, the signature.
pub const BLOCK_LEN: usize = 8 + 32 + 4 + 64;
/// Flag: the owner allows this image below the running image's security version.
pub const DOWNGRADE: u32 = 0b1;
/// Every flag this format defines; a block with another bit set is refused, so that a
/// later flag that restricts an image is never read as absent.
const KNOWN_FLAGS: u32 = DOWNGRADE;
/// Put before the digest in the signed message, so that no signature made for
/// anything else verifies as an image's.
const DOMAIN: &[u8; 24] = b"base-controller image 1\x00";
const MESSAGE_LEN: usize = DOMAIN.len() + SHA256_LEN + 4;

/// Which images this build activates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trust<'a> {
    /// A development build (no key was given to the build): any image the bootloader
    /// would start, signed or not, with any security version.
    Development,
    /// Only images signed by one of these keys.
    Keys(&'a [PublicKey]),
}

impl<'a> Trust<'a> {
    /// What a build given these keys trusts: no key makes a development build.
    pub const fn of_keys(keys: &'a [PublicKey]) -> Self {
        if keys.is_empty() {
            Self::Development
        } else {
            Self::Keys(keys)
        }
    }

    pub const fn accepts_unsigned(&self) -> bool {
        matches!(self, Self::Development)
    }
}

/// The block after a signed image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SignatureBlock {
    pub key: PublicKey,
    pub flags: u32,
    pub signature: [u8; 64],
}

impl SignatureBlock {
    /// The block in `bytes`, which must be exactly one block; `None` otherwise.
    pub fn parse(bytes: &[u8]) -> Option<Self> {
        let bytes: &[u8; BLOCK_LEN] = bytes.try_into().ok()?;
        let (magic, rest) = bytes.split_at(BLOCK_MAGIC.len());
        if magic != BLOCK_MAGIC {
            return None;
        }
        let (key, rest) = rest.split_at(32);
        let (flags, signature) = rest.split_at(4);
        Some(Self {
            key: key.try_into().ok()?,
            flags: u32::from_le_bytes(flags.try_into().ok()?),
            signature: signature.try_into().ok()?,
        })
    }

    pub fn to_bytes(&self) -> [u8; BLOCK_LEN] {
        let mut bytes = [0; BLOCK_LEN];
        bytes[..8].copy_from_slice(&BLOCK_MAGIC);
        bytes[8..40].copy_from_slice(&self.key);
        bytes[40..44].copy_from_slice(&self.flags.to_le_bytes());
        bytes[44..].copy_from_slice(&self.signature);
        bytes
    }

    pub const fn allows_downgrade(&self) -> bool {
        self.flags & DOWNGRADE != 0
    }
}

/// What is signed: the domain, the image's appended SHA-256, the flags (LE).
pub fn signed_message(digest: &[u8; SHA256_LEN], flags: u32) -> [u8; MESSAGE_LEN] {
    let mut message = [0; MESSAGE_LEN];
    message[..DOMAIN.len()].copy_from_slice(DOMAIN);
    message[DOMAIN.len()..DOMAIN.len() + SHA256_LEN].copy_from_slice(digest);
    message[DOMAIN.len() + SHA256_LEN..].copy_from_slice(&flags.to_le_bytes());
    message
}

/// Why a controller that trusts keys refuses an image. The update's refusal
/// `Untrusted` carries [`code`](Self::code) as its detail; `SecurityDowngrade` has an
/// error of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SignatureError {
    /// No signature block after the image.
    NotSigned,
    /// Signed by a key this controller does not trust.
    UnknownKey,
    /// The signature does not match the image and flags (a byte changed after
    /// signing), or the block is not well formed (a flag this format does not know).
    BadSignature,
    /// Below the running image's security version, and the owner did not sign a
    /// downgrade.
    SecurityDowngrade,
}

impl SignatureError {
    /// A stable code for the wire (the detail of the `Untrusted` refusal).
    pub const fn code(self) -> u8 {
        match self {
            Self::NotSigned => 1,
            Self::UnknownKey => 2,
            Self::BadSignature => 3,
            Self::SecurityDowngrade => 4,
        }
    }
}

/// Whether `trust` lets an image be activated: `block` is what follows the image's
/// appended `digest` (already checked against the image), `security_version` the
/// image's, `running_security_version` the floor. Returns the signer, if signed.
pub fn check(
    trust: Trust<'_>,
    block: Option<&SignatureBlock>,
    digest: &[u8; SHA256_LEN],
    security_version: u32,
    running_security_version: u32,
) -> Result<Option<PublicKey>, SignatureError> {
    let keys = match trust {
        Trust::Development => return Ok(block.map(|block| block.key)),
        Trust::Keys(keys) => keys,
    };
    let block = block.ok_or(SignatureError::NotSigned)?;
    if !keys.contains(&block.key) {
        return Err(SignatureError::UnknownKey);
    }
    if block.flags & !KNOWN_FLAGS != 0 {
        return Err(SignatureError::BadSignature);
    }
    // The crate refuses a non-canonical `S`, so no second form of a signature verifies.
    let key = ed25519_compact::PublicKey::new(block.key);
    key.verify(
        signed_message(digest, block.flags),
        &Signature::new(block.signature),
    )
    .map_err(|_| SignatureError::BadSignature)?;
    if security_version < running_security_version && !block.allows_downgrade() {
        return Err(SignatureError::SecurityDowngrade);
    }
    Ok(Some(block.key))
}

/// The public key of a secret key (the 32-byte seed ed25519 key files hold).
pub fn public_key(secret: &[u8; 32]) -> PublicKey {
    *KeyPair::from_seed(Seed::new(*secret)).pk
}

/// Signs `image` with `secret`: returns how many bytes of `image` the signed image
/// keeps (up to its appended SHA-256; an earlier signature or padding after it is
/// dropped) and the block that follows them. Refused when the image fails the
/// bootloader's checks: a signature over a broken image would be no use.
pub fn sign(
    image: &[u8],
    secret: &[u8; 32],
    flags: u32,
) -> Result<(usize, SignatureBlock), ImageError> {
    let len = image::verify_whole(image, image.len())?;
    let digest: &[u8; SHA256_LEN] = image[len - SHA256_LEN..len]
        .try_into()
        .map_err(|_| ImageError::BadDigest)?;
    Ok((len, sign_digest(digest, secret, flags)))
}

/// The block for an image whose appended SHA-256 is `digest`.
pub fn sign_digest(digest: &[u8; SHA256_LEN], secret: &[u8; 32], flags: u32) -> SignatureBlock {
    let pair = KeyPair::from_seed(Seed::new(*secret));
    // Deterministic (no noise): the same image, key and flags sign to the same bytes.
    let signature = pair.sk.sign(signed_message(digest, flags), None);
    SignatureBlock {
        key: *pair.pk,
        flags,
        signature: *signature,
    }
}

/// The signature block after the image [`WholeImageCheck`] was fed, if the bytes after
/// its appended SHA-256 are exactly one.
pub fn block_after(check: &WholeImageCheck) -> Option<SignatureBlock> {
    SignatureBlock::parse(check.trailer()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::update::image::{Chip, reseal, synthetic_image, verify_whole};

    const OWNER: [u8; 32] = [0x11; 32];
    const STRANGER: [u8; 32] = [0x22; 32];

    fn image() -> std::vec::Vec<u8> {
        synthetic_image(Chip::Esp32c3, "base-controller", "0.3.0", &[5; 900])
    }

    /// The image signed with `secret`, as `basectl firmware sign` writes it.
    fn signed(image: &[u8], secret: &[u8; 32], flags: u32) -> std::vec::Vec<u8> {
        let (len, block) = sign(image, secret, flags).unwrap();
        [&image[..len], &block.to_bytes()[..]].concat()
    }

    /// What the controller checks at FINISH, from the signed file's bytes.
    fn verdict(
        file: &[u8],
        keys: &[PublicKey],
        security_version: u32,
        running_security_version: u32,
    ) -> Result<Option<PublicKey>, SignatureError> {
        let mut whole = WholeImageCheck::new();
        whole.feed(file);
        whole.finish().expect("the bootloader's checks pass");
        check(
            Trust::Keys(keys),
            block_after(&whole).as_ref(),
            whole.digest().unwrap(),
            security_version,
            running_security_version,
        )
    }

    #[test]
    fn an_image_signed_by_a_trusted_key_passes_and_names_its_signer() {
        let owner = public_key(&OWNER);
        let file = signed(&image(), &OWNER, 0);
        assert_eq!(file.len(), image().len() + BLOCK_LEN);
        assert_eq!(verdict(&file, &[owner], 0, 0), Ok(Some(owner)));
        // The bootloader's checks ignore the block: the signed file boots as it is.
        assert_eq!(verify_whole(&file, file.len()), Ok(image().len()));
    }

    #[test]
    fn unsigned_and_strangers_images_are_refused_by_a_build_with_a_key() {
        let owner = public_key(&OWNER);
        assert_eq!(
            verdict(&image(), &[owner], 0, 0),
            Err(SignatureError::NotSigned)
        );
        let strangers = signed(&image(), &STRANGER, 0);
        assert_eq!(
            verdict(&strangers, &[owner], 0, 0),
            Err(SignatureError::UnknownKey)
        );
        // Padding after the digest is no signature either.
        let mut padded = image();
        padded.extend_from_slice(&[0xFF; 16]);
        assert_eq!(
            verdict(&padded, &[owner], 0, 0),
            Err(SignatureError::NotSigned)
        );
    }

    #[test]
    fn a_byte_changed_after_signing_is_refused_wherever_it_is() {
        let owner = public_key(&OWNER);
        let file = signed(&image(), &OWNER, 0);
        let image_len = image().len();
        // A byte of the image, with the checksum and SHA-256 made to fit again (a
        // careless change fails the bootloader's checks before the signature's).
        for at in [40, 600, image_len - 40] {
            let mut forged = file.clone();
            forged[at] ^= 0x20;
            reseal(&mut forged[..image_len]);
            assert_eq!(
                verdict(&forged, &[owner], 0, 0),
                Err(SignatureError::BadSignature),
                "byte {at}"
            );
        }
        // The block's flags (a downgrade claimed) and its signature.
        for at in [image_len + 40, image_len + 60, image_len + BLOCK_LEN - 1] {
            let mut forged = file.clone();
            forged[at] ^= 0x01;
            assert_eq!(
                verdict(&forged, &[owner], 0, 0),
                Err(SignatureError::BadSignature),
                "block byte {}",
                at - image_len
            );
        }
    }

    #[test]
    fn a_flag_this_format_does_not_know_is_refused_though_signed() {
        let owner = public_key(&OWNER);
        let file = signed(&image(), &OWNER, 1 << 7);
        assert_eq!(
            verdict(&file, &[owner], 0, 0),
            Err(SignatureError::BadSignature)
        );
    }

    #[test]
    fn below_the_running_security_version_only_a_signed_downgrade_passes() {
        let owner = public_key(&OWNER);
        let plain = signed(&image(), &OWNER, 0);
        assert_eq!(
            verdict(&plain, &[owner], 1, 2),
            Err(SignatureError::SecurityDowngrade)
        );
        assert_eq!(verdict(&plain, &[owner], 2, 2), Ok(Some(owner)));
        assert_eq!(verdict(&plain, &[owner], 3, 2), Ok(Some(owner)));
        let downgrade = signed(&image(), &OWNER, DOWNGRADE);
        assert_eq!(verdict(&downgrade, &[owner], 1, 2), Ok(Some(owner)));
    }

    #[test]
    fn a_development_build_takes_any_image() {
        let mut whole = WholeImageCheck::new();
        whole.feed(&image());
        assert_eq!(
            check(Trust::Development, None, whole.digest().unwrap(), 0, 9),
            Ok(None)
        );
        assert!(Trust::Development.accepts_unsigned());
        assert!(!Trust::Keys(&[]).accepts_unsigned());
    }

    #[test]
    fn re_signing_replaces_the_old_signature() {
        let owner = public_key(&OWNER);
        let strangers = signed(&image(), &STRANGER, 0);
        let file = signed(&strangers, &OWNER, 0);
        assert_eq!(file.len(), image().len() + BLOCK_LEN);
        assert_eq!(verdict(&file, &[owner], 0, 0), Ok(Some(owner)));
    }

    #[test]
    fn a_block_of_the_wrong_length_or_magic_is_no_block() {
        let block = SignatureBlock {
            key: [1; 32],
            flags: DOWNGRADE,
            signature: [2; 64],
        };
        let bytes = block.to_bytes();
        assert_eq!(SignatureBlock::parse(&bytes), Some(block));
        assert_eq!(SignatureBlock::parse(&bytes[..BLOCK_LEN - 1]), None);
        let mut other = bytes;
        other[0] ^= 1;
        assert_eq!(SignatureBlock::parse(&other), None);
    }
}
